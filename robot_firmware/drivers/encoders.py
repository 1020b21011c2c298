"""Encoder driver: wheel positions and speeds from the QEP IPs (5C level 1, connection).

Each wheel has one QEP instance (`qep0`..`qep3`) whose COUNT register is the 4x-decoded
position as a 32-bit two's complement number that wraps at +/-2**31. The driver turns
it into an unbounded int64 running count: the first successful read of a wheel sets
its running count to COUNT, and every later read adds the wrapped difference

    delta = as_signed32(COUNT_now - COUNT_before)

so a wrap between two reads is invisible as long as the wheel moved fewer than 2**31
counts between them (at 100 Hz that is over 200 million counts per second).

Speeds come from SPEED_FILTERED, the counts of the last speed window after the speed
filter (bypass at reset, so equal to SPEED):

    speed_counts_per_s = SPEED_FILTERED * f_C0 / WINDOW_TICKS

with f_C0 read from the clock block and WINDOW_TICKS from each QEP, both read once and
then reused (`refresh_speed_timebase` reads them again after a clock or window change).

A refused read is counted in `bus_errors` and leaves that wheel's value as it was.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import qep as qep_map
from robot_firmware.fpga.address_map import CLOCK_BASE, N_WHEELS, QEP_BASES
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.clock import C0_HZ
from robot_firmware.fpga.registers import as_signed32

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


class EncoderDriver:
    """Unwrapped 4x encoder counts and windowed speeds of every wheel."""

    def __init__(self, bus: Bus, wheel_count: int = N_WHEELS) -> None:
        if not 1 <= wheel_count <= N_WHEELS:
            raise ValueError(f"wheel_count {wheel_count} outside 1..{N_WHEELS}")
        self._port = RegisterPort(bus)
        self.wheel_count = wheel_count
        bases = QEP_BASES[:wheel_count]
        self._count_addresses = tuple(base + qep_map.COUNT.offset for base in bases)
        self._speed_addresses = tuple(base + qep_map.SPEED_FILTERED.offset for base in bases)
        self._window_addresses = tuple(base + qep_map.WINDOW_TICKS.offset for base in bases)
        self._last_words: list[int | None] = [None] * wheel_count
        self._counts = np.zeros(wheel_count, dtype=np.int64)
        self._speeds_counts_per_s = np.full(wheel_count, np.nan)
        self._clock_hz: int | None = None
        self._window_ticks: list[int | None] = [None] * wheel_count

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    def read_counts(self) -> IntArray:
        """Running 4x-decoded count per wheel, shape (wheel_count,), unbounded.

        0 for a wheel whose COUNT was never read successfully; the last value for a
        wheel whose read is refused now.
        """
        for wheel, address in enumerate(self._count_addresses):
            word = self._port.read(address)
            if word is None:
                continue
            previous = self._last_words[wheel]
            if previous is None:
                self._counts[wheel] = as_signed32(word)
            else:
                self._counts[wheel] += as_signed32(word - previous)
            self._last_words[wheel] = word
        return self._counts.copy()

    def read_speeds_counts_per_s(self) -> FloatArray:
        """Filtered wheel speed in 4x counts per second, shape (wheel_count,).

        NaN for a wheel whose speed was never read or whose window is 0 (latch
        stopped); the last value for a wheel whose read is refused now.
        """
        if self._clock_hz is None or None in self._window_ticks:
            self.refresh_speed_timebase()
        for wheel, address in enumerate(self._speed_addresses):
            window_ticks = self._window_ticks[wheel]
            if self._clock_hz is None or window_ticks is None:
                continue
            word = self._port.read(address)
            if word is None:
                continue
            if window_ticks == 0:
                self._speeds_counts_per_s[wheel] = np.nan
            else:
                speed = as_signed32(word) * self._clock_hz / window_ticks
                self._speeds_counts_per_s[wheel] = speed
        return self._speeds_counts_per_s.copy()

    def refresh_speed_timebase(self) -> None:
        """Read the fabric clock and every speed window again (after changing either)."""
        clock_hz = self._port.read(CLOCK_BASE + C0_HZ.offset)
        if clock_hz is not None:
            self._clock_hz = clock_hz
        for wheel, address in enumerate(self._window_addresses):
            window_ticks = self._port.read(address)
            if window_ticks is not None:
                self._window_ticks[wheel] = window_ticks

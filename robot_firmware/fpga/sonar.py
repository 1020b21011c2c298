"""Ultrasound ranger IP: measures the echo pulse width of one sonar in fabric clock ticks.

Writing START to TRIGGER fires a ping and sets BUSY. The world tells the IP, through
`hw_set_echo_time`, the round-trip time of the echo the sonar would receive now
(None when there is none); the IP samples it at the trigger. After the echo time has
passed (`tick`), the width in fabric ticks is latched into WIDTH_TICKS, pushed
through the sonar filter into FILTERED_TICKS, SAMPLES increments and DATA_READY is
set. With no echo, or one longer than TIMEOUT_TICKS, the measurement ends after
TIMEOUT_TICKS with the TIMEOUT event and WIDTH_TICKS unchanged. A trigger while BUSY
is ignored and sets MISSED. EVENTS clears when read.

The range is width / f_fabric * c / 2 with c = SPEED_OF_SOUND_MPS;
`range_m_for_width_ticks` and `echo_time_s_for_range_m` do that conversion.

A register fault (robot_firmware/fpga/faults.py) can block the echo (`hw_block_echo`): every
measurement triggered while it lasts ends in TIMEOUT.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from robot_firmware.fpga.clock import DEFAULT_FABRIC_CLOCK_HZ
from robot_firmware.fpga.registers import (
    WORD_MASK,
    Access,
    Field,
    Peripheral,
    Register,
    slices_before_due,
)

SPEED_OF_SOUND_MPS = 343.0
NS_PER_S = 1_000_000_000
RESET_TIMEOUT_TICKS = 1_500_000  # 30 ms at the 50 MHz reset fabric clock, about 5.1 m


def echo_time_s_for_range_m(range_m: float) -> float:
    """Round-trip echo time of an obstacle at `range_m`."""
    return 2.0 * range_m / SPEED_OF_SOUND_MPS


def range_m_for_width_ticks(width_ticks: int, fabric_clock_hz: float) -> float:
    """Obstacle range for an echo pulse of `width_ticks` fabric clock cycles."""
    return width_ticks / fabric_clock_hz * SPEED_OF_SOUND_MPS / 2.0


TRIGGER = Register(
    name="TRIGGER",
    offset=0x00,
    access=Access.WO,
    reset=0,
    fields=(
        Field(
            name="START", msb=0, lsb=0, doc="1 fires a ping; ignored (and MISSED set) while BUSY"
        ),
    ),
    doc="Measurement trigger.",
    affects=("STATUS", "EVENTS"),
)
TRIGGER_START = TRIGGER.field("START")
STATUS = Register(
    name="STATUS",
    offset=0x04,
    access=Access.RO,
    reset=0,
    fields=(Field(name="BUSY", msb=0, lsb=0, doc="a measurement is in progress"),),
    doc="Ranger state.",
)
STATUS_BUSY = STATUS.field("BUSY")
EVENTS = Register(
    name="EVENTS",
    offset=0x08,
    access=Access.RC,
    reset=0,
    fields=(
        Field(name="DATA_READY", msb=0, lsb=0, doc="a new WIDTH_TICKS was latched"),
        Field(
            name="TIMEOUT",
            msb=1,
            lsb=1,
            doc="a measurement ended with no echo within TIMEOUT_TICKS",
        ),
        Field(name="MISSED", msb=2, lsb=2, doc="a trigger arrived while BUSY"),
    ),
    doc="Measurement events; a read returns and clears them.",
)
EVENTS_DATA_READY = EVENTS.field("DATA_READY")
EVENTS_TIMEOUT = EVENTS.field("TIMEOUT")
EVENTS_MISSED = EVENTS.field("MISSED")
WIDTH_TICKS = Register(
    name="WIDTH_TICKS",
    offset=0x0C,
    access=Access.RO,
    reset=0,
    fields=(Field(name="TICKS", msb=31, lsb=0, doc="fabric clock cycles"),),
    doc="Echo pulse width of the last measurement.",
)
FILTERED_TICKS = Register(
    name="FILTERED_TICKS",
    offset=0x10,
    access=Access.RO,
    reset=0,
    fields=(Field(name="TICKS", msb=31, lsb=0, doc="fabric clock cycles"),),
    doc="WIDTH_TICKS after the sonar filter.",
)
TIMEOUT_TICKS = Register(
    name="TIMEOUT_TICKS",
    offset=0x14,
    access=Access.RW,
    reset=RESET_TIMEOUT_TICKS,
    fields=(Field(name="TICKS", msb=31, lsb=0, doc="fabric clock cycles"),),
    doc="Longest echo accepted; a measurement gives up after it.",
)
SAMPLES = Register(
    name="SAMPLES",
    offset=0x18,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNT", msb=31, lsb=0, doc="echoes latched since reset, wraps"),),
    doc="Number of echoes measured.",
)

REGISTERS = (TRIGGER, STATUS, EVENTS, WIDTH_TICKS, FILTERED_TICKS, TIMEOUT_TICKS, SAMPLES)


def _identity(sample: int) -> int:
    return sample


def _fixed_clock_hz() -> int:
    return DEFAULT_FABRIC_CLOCK_HZ


class Sonar(Peripheral):
    """Triggered echo-width timer of one ultrasound ranger."""

    TITLE = "Ultrasound ranger"
    SUMMARY = (
        "One instance per sonar. TRIGGER starts a measurement; after the echo returns, "
        "WIDTH_TICKS holds its width in fabric cycles (range = width / f_C0 * 343 m/s / 2), "
        "FILTERED_TICKS the output of sonar_filter, and EVENTS.DATA_READY is set. No echo "
        "within TIMEOUT_TICKS sets EVENTS.TIMEOUT instead."
    )

    def __init__(
        self,
        name: str,
        clock_hz: Callable[[], int] = _fixed_clock_hz,
        width_filter: Callable[[int], int] = _identity,
    ) -> None:
        super().__init__(name, REGISTERS)
        self._clock_hz = clock_hz
        self._width_filter = width_filter
        self._echo_time_s: float | None = None
        self._remaining_ns: int | None = None
        self._result_ticks: int | None = None
        self._echo_blocked = False
        self._write_actions = {TRIGGER.offset: self._on_trigger}

    def tick(self, dt_ns: int) -> None:
        if self._remaining_ns is None:
            return
        self._remaining_ns -= dt_ns
        if self._remaining_ns > 0:
            return
        self._remaining_ns = None
        self._store(STATUS, 0)
        if self._result_ticks is None:
            self._set_bits(EVENTS_TIMEOUT)
            return
        self._store(WIDTH_TICKS, self._result_ticks)
        self._store(FILTERED_TICKS, self._width_filter(self._result_ticks))
        self._store(SAMPLES, (self._get(SAMPLES) + 1) & WORD_MASK)
        self._set_bits(EVENTS_DATA_READY)

    def quiet_slices(self, slice_ns: int) -> int | None:
        if self._remaining_ns is None:
            return None
        return slices_before_due(self._remaining_ns, slice_ns)

    # -- hardware side ---------------------------------------------------------------

    def hw_set_echo_time(self, echo_time_s: float | None) -> None:
        """Round-trip time of the echo a ping would get now; None (or not finite, < 0) = none."""
        if echo_time_s is None or not math.isfinite(echo_time_s) or echo_time_s < 0.0:
            self._echo_time_s = None
        else:
            self._echo_time_s = float(echo_time_s)

    def hw_busy(self) -> bool:
        return self._remaining_ns is not None

    def hw_block_echo(self, blocked: bool) -> None:
        """Fault injection: while blocked the receiver hears no echo (a cut transducer), so
        each measurement triggered ends after TIMEOUT_TICKS with TIMEOUT, WIDTH_TICKS kept."""
        self._echo_blocked = blocked

    # -- side effects ----------------------------------------------------------------

    def _on_trigger(self, value: int) -> None:
        if not TRIGGER_START.extract(value):
            return
        if self._remaining_ns is not None:
            self._set_bits(EVENTS_MISSED)
            return
        clock_hz = max(1, self._clock_hz())
        timeout_ticks = self._get(TIMEOUT_TICKS)
        echo_s = None if self._echo_blocked else self._echo_time_s
        width_ticks = None
        if echo_s is not None:
            echo_ticks = echo_s * clock_hz
            if echo_ticks < timeout_ticks + 1:  # a longer echo times out (and may not fit an int)
                width_ticks = round(echo_ticks)
        if width_ticks is None or width_ticks > timeout_ticks:
            self._result_ticks = None
            self._remaining_ns = timeout_ticks * NS_PER_S // clock_hz
        else:
            self._result_ticks = width_ticks
            self._remaining_ns = width_ticks * NS_PER_S // clock_hz
        self._store(STATUS, STATUS_BUSY.mask)

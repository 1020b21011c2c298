"""Sonar driver: obstacle gaps from the ultrasound rangers (5C levels 1 and 2).

Each ranger (`sonar0`..) measures the width of its echo pulse in fabric clock cycles
after a TRIGGER. The gap to the obstacle is

    gap_m = FILTERED_TICKS / f_C0 * 343 m/s / 2

with f_C0 the fabric clock read from the clock block at the trigger, the clock the
ranger counted in. FILTERED_TICKS is WIDTH_TICKS after the sonar filter block, which
is in bypass at reset (so equal to WIDTH_TICKS) until `configure_filter` changes it.

`poll` reads each ranger's EVENTS register, which clears as it is read:

* DATA_READY: a new width was latched; the gap is updated from FILTERED_TICKS;
* TIMEOUT: the measurement ended without an echo; the gap becomes inf;
* both (two measurements ended since the last poll, order unknown): the finite gap
  wins, the cautious choice for obstacle avoidance;
* MISSED: a trigger arrived while busy; counted in `missed_triggers`.

A ranger with no event keeps its previous gap (inf before its first measurement).
A refused access is counted in `bus_errors`: a refused EVENTS or FILTERED_TICKS read
leaves that gap as it was, so a driver built for more rangers than the image has
keeps working for those that exist.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import digital_filter as filter_map
from robot_firmware.fpga import sonar as sonar_map
from robot_firmware.fpga.address_map import CLOCK_BASE, MAX_SONAR, SONAR_FILTER_BASE, sonar_base
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.clock import C0_HZ, DEFAULT_FABRIC_CLOCK_HZ
from robot_firmware.fpga.digital_filter import MAX_WINDOW, FilterMode
from robot_firmware.fpga.sonar import range_m_for_width_ticks

FloatArray = NDArray[np.float64]

_START = sonar_map.TRIGGER_START.mask
_DATA_READY = sonar_map.EVENTS_DATA_READY.mask
_TIMEOUT = sonar_map.EVENTS_TIMEOUT.mask
_MISSED = sonar_map.EVENTS_MISSED.mask


class SonarDriver:
    """Triggers every ranger together and collects their gaps in metres."""

    def __init__(self, bus: Bus, sonar_count: int) -> None:
        if not 1 <= sonar_count <= MAX_SONAR:
            raise ValueError(f"sonar_count {sonar_count} outside 1..{MAX_SONAR}")
        self._port = RegisterPort(bus)
        self.sonar_count = sonar_count
        bases = tuple(sonar_base(i) for i in range(sonar_count))
        self._trigger_addresses = tuple(base + sonar_map.TRIGGER.offset for base in bases)
        self._events_addresses = tuple(base + sonar_map.EVENTS.offset for base in bases)
        self._width_addresses = tuple(base + sonar_map.FILTERED_TICKS.offset for base in bases)
        self._gaps_m = np.full(sonar_count, np.inf)
        self._clock_hz: int = DEFAULT_FABRIC_CLOCK_HZ
        self.missed_triggers = 0
        """Triggers the rangers ignored because they were still measuring."""

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    def trigger_all(self) -> None:
        """Start a measurement on every ranger (a busy ranger ignores it and reports MISSED)."""
        clock_hz = self._port.read(CLOCK_BASE + C0_HZ.offset)
        if clock_hz:
            self._clock_hz = clock_hz
        for address in self._trigger_addresses:
            self._port.write(address, _START)

    def poll(self) -> tuple[FloatArray, bool]:
        """Gap per ranger in metres (inf = no echo), and whether any is new since the last poll.

        Gaps of rangers with nothing new keep their previous value.
        """
        fresh = False
        for i in range(self.sonar_count):
            events = self._port.read(self._events_addresses[i])
            if events is None:
                continue
            if events & _MISSED:
                self.missed_triggers += 1
            if events & _DATA_READY:
                width_ticks = self._port.read(self._width_addresses[i])
                if width_ticks is None:
                    continue
                self._gaps_m[i] = range_m_for_width_ticks(width_ticks, self._clock_hz)
                fresh = True
            elif events & _TIMEOUT:
                self._gaps_m[i] = np.inf
                fresh = True
        return self._gaps_m.copy(), fresh

    def configure_filter(self, mode: FilterMode = FilterMode.BYPASS, window: int = 1) -> bool:
        """Set the sonar filter block to `mode` over `window` samples (1..16); empties its history.

        Returns whether the block's STATUS shows that setting in effect.
        """
        if not 1 <= window <= MAX_WINDOW:
            raise ValueError(f"filter window {window} outside 1..{MAX_WINDOW}")
        mode = FilterMode(mode)
        self._port.write(SONAR_FILTER_BASE + filter_map.MODE.offset, int(mode))
        self._port.write(SONAR_FILTER_BASE + filter_map.WINDOW.offset, window)
        status = self._port.read(SONAR_FILTER_BASE + filter_map.STATUS.offset)
        if status is None:
            return False
        return (
            filter_map.STATUS_MODE.extract(status) == mode
            and filter_map.STATUS_LENGTH.extract(status) == window
        )

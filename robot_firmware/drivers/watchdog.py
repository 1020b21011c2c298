"""Watchdog driver: arms the motor watchdog and kicks it every control period (5C level 5).

The watchdog IP counts down from TIMEOUT_MS and, at zero, holds every PWM output low
until the next good kick (KICK written with the key 0x600DD06E). A new TIMEOUT_MS is
used from the next kick, so `configure` writes the timeout, enables the count and then
kicks. The firmware kicks once per control tick, after writing the wheel commands; a
firmware that stalls for longer than the timeout stops the robot.

A refused access is counted in `bus_errors`; `expired` then repeats the last state it
read (False before the first successful read).
"""

from __future__ import annotations

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import watchdog as watchdog_map
from robot_firmware.fpga.address_map import WATCHDOG_BASE
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.watchdog import KICK_MAGIC

_MAX_TIMEOUT_MS = watchdog_map.TIMEOUT_MS_MS.mask
_EN = watchdog_map.CTRL_EN.mask
_EXPIRED = watchdog_map.STATUS_EXPIRED.mask


class WatchdogDriver:
    """Timeout, enable and kick of the motor watchdog."""

    def __init__(self, bus: Bus) -> None:
        self._port = RegisterPort(bus)
        self._expired = False

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    def configure(self, timeout_ms: int) -> None:
        """Set the timeout (1..65535 ms), enable the count and kick so the timeout applies now."""
        if not 1 <= timeout_ms <= _MAX_TIMEOUT_MS:
            raise ValueError(f"watchdog timeout {timeout_ms} ms outside 1..{_MAX_TIMEOUT_MS}")
        self._port.write(WATCHDOG_BASE + watchdog_map.TIMEOUT_MS.offset, timeout_ms)
        self._port.write(WATCHDOG_BASE + watchdog_map.CTRL.offset, _EN)
        self.kick()

    def kick(self) -> None:
        """Reload the count; ends a cut if the watchdog had expired."""
        self._port.write(WATCHDOG_BASE + watchdog_map.KICK.offset, KICK_MAGIC)

    def expired(self) -> bool:
        """Whether the timeout elapsed without a kick, so the motor outputs are cut."""
        status = self._port.read(WATCHDOG_BASE + watchdog_map.STATUS.offset)
        if status is not None:
            self._expired = bool(status & _EXPIRED)
        return self._expired

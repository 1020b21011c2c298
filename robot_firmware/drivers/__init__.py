"""Processor-side drivers of the FPGA IPs: the HPS half of 5C levels 1 and 5.

Every driver talks only to a `robot_firmware.fpga.bus.Bus`, with aligned 32-bit
reads and writes at the addresses of `robot_firmware.fpga.address_map` plus the
register offsets declared by the fpga modules, as a Linux driver would through a
mapped bridge. A refused access is never an exception: each driver counts it in
`bus_errors` and carries on with its last good value. The one exception is
`IncompatibleFabricError`, raised by `SystemProbe.identify` at boot.

A typical control tick: `encoders.read_counts()`, `sonar.poll()`,
`positioning.read_fix()`, `motors.set_duty(...)`, `watchdog.kick()`; every 50 ms
also `sonar.trigger_all()`.
"""

from __future__ import annotations

from dataclasses import dataclass

from robot_firmware.drivers.encoders import EncoderDriver
from robot_firmware.drivers.motors import MotorDriver
from robot_firmware.drivers.positioning import PoseFix, PositioningDriver
from robot_firmware.drivers.sonar import SonarDriver
from robot_firmware.drivers.system import IncompatibleFabricError, SystemInfo, SystemProbe
from robot_firmware.drivers.watchdog import WatchdogDriver
from robot_firmware.fpga.bus import Bus


@dataclass(frozen=True)
class Drivers:
    """One driver of each kind, all on the same bus."""

    system: SystemProbe
    motors: MotorDriver
    encoders: EncoderDriver
    sonar: SonarDriver
    watchdog: WatchdogDriver
    positioning: PositioningDriver

    @classmethod
    def attach(cls, bus: Bus, sonar_count: int) -> Drivers:
        """Build every driver on `bus` (no bus access happens here)."""
        return cls(
            system=SystemProbe(bus),
            motors=MotorDriver(bus),
            encoders=EncoderDriver(bus),
            sonar=SonarDriver(bus, sonar_count),
            watchdog=WatchdogDriver(bus),
            positioning=PositioningDriver(bus),
        )

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of all drivers together."""
        return (
            self.system.bus_errors
            + self.motors.bus_errors
            + self.encoders.bus_errors
            + self.sonar.bus_errors
            + self.watchdog.bus_errors
            + self.positioning.bus_errors
        )


__all__ = [
    "Drivers",
    "EncoderDriver",
    "IncompatibleFabricError",
    "MotorDriver",
    "PoseFix",
    "PositioningDriver",
    "SonarDriver",
    "SystemInfo",
    "SystemProbe",
    "WatchdogDriver",
]

"""FPGA register model of one robot: the IP peripherals, the bus the firmware uses, the fabric.

The firmware reaches sensors and motors only through `Bus.read` / `Bus.write` at
absolute addresses behind the lightweight HPS-to-FPGA bridge (see `address_map`);
the world reaches the same IPs through the `hw_*` side of `Fabric`. Nothing here
opens a socket, starts a thread or reads a clock: time comes in through `tick(dt_ns)`.
"""

from robot_firmware.fpga.bus import Bus, BusAccess, BusErrorKind, BusOp, BusResult, RecordingBus
from robot_firmware.fpga.fabric import Actuation, Fabric, FabricConfig
from robot_firmware.fpga.positioning import PositionFix
from robot_firmware.fpga.registers import (
    Access,
    Field,
    FieldHandle,
    Peripheral,
    Register,
    RegisterAccessError,
    as_signed32,
    as_unsigned32,
)

__all__ = [
    "Access",
    "Actuation",
    "Bus",
    "BusAccess",
    "BusErrorKind",
    "BusOp",
    "BusResult",
    "Fabric",
    "FabricConfig",
    "Field",
    "FieldHandle",
    "Peripheral",
    "PositionFix",
    "RecordingBus",
    "Register",
    "RegisterAccessError",
    "as_signed32",
    "as_unsigned32",
]

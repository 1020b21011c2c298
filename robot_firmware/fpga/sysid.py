"""System ID IP: tells a driver which FPGA image it talks to and what the image contains.

The driver checks ID and VERSION before touching anything else, reads CAPS to learn
how many encoder, PWM and sonar instances exist, and may use SCRATCH to test the bus.
"""

from __future__ import annotations

from robot_firmware.fpga.address_map import DEFAULT_N_SONAR, N_WHEELS
from robot_firmware.fpga.registers import Access, Field, Peripheral, Register

SYSTEM_ID = 0x5357_524D  # ASCII "SWRM"
VERSION_MAJOR = 1
VERSION_MINOR = 0
VERSION_PATCH = 0
BUILD_NUMBER = 1

ID = Register(
    "ID",
    0x00,
    Access.RO,
    SYSTEM_ID,
    (Field("ID", 31, 0, "0x5357524D, ASCII 'SWRM'"),),
    "Fixed identifier of the swarm-robot FPGA image.",
)
VERSION = Register(
    "VERSION",
    0x04,
    Access.RO,
    (VERSION_MAJOR << 24) | (VERSION_MINOR << 16) | VERSION_PATCH,
    (
        Field("MAJOR", 31, 24, "incompatible register map changes"),
        Field("MINOR", 23, 16, "compatible additions"),
        Field("PATCH", 15, 0, "fixes with no register map change"),
    ),
    "Register map version.",
)
BUILD = Register(
    "BUILD",
    0x08,
    Access.RO,
    BUILD_NUMBER,
    (Field("BUILD", 31, 0, "build number of the image"),),
    "Build number, increases with every image.",
)
CAPS = Register(
    "CAPS",
    0x0C,
    Access.RO,
    N_WHEELS | (N_WHEELS << 4) | (DEFAULT_N_SONAR << 8),
    (
        Field("N_QEP", 3, 0, "encoder interfaces"),
        Field("N_PWM", 7, 4, "PWM generators"),
        Field("N_SONAR", 12, 8, "ultrasound rangers (reset shown for 12)"),
    ),
    "Instance counts of the image.",
)
SCRATCH = Register(
    "SCRATCH",
    0x10,
    Access.RW,
    0,
    (Field("VALUE", 31, 0, "any value; reads back what was written"),),
    "Scratch word for bus tests.",
)

REGISTERS = (ID, VERSION, BUILD, CAPS, SCRATCH)


class SystemId(Peripheral):
    """Identification and capabilities of the FPGA image."""

    TITLE = "System ID"
    SUMMARY = (
        "Identifies the image (ID, VERSION, BUILD) and lists its instance counts (CAPS). "
        "SCRATCH is free for bus tests."
    )

    def __init__(
        self,
        name: str = "sysid",
        n_qep: int = N_WHEELS,
        n_pwm: int = N_WHEELS,
        n_sonar: int = DEFAULT_N_SONAR,
    ) -> None:
        caps = 0
        for field_name, count in (("N_QEP", n_qep), ("N_PWM", n_pwm), ("N_SONAR", n_sonar)):
            f = CAPS.field(field_name)
            if not 0 <= count < (1 << f.width):
                raise ValueError(f"{field_name}={count} does not fit CAPS")
            caps = f.insert(caps, count)
        super().__init__(name, tuple(CAPS.with_reset(caps) if r is CAPS else r for r in REGISTERS))

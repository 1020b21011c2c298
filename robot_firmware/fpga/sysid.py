"""System ID IP: tells a driver which FPGA image it talks to and what the image contains.

The driver checks ID and VERSION before touching anything else, reads CAPS to learn
how many encoder, PWM and sonar instances exist, and may use SCRATCH to test the bus.
"""

from __future__ import annotations

from robot_firmware.fpga.address_map import DEFAULT_N_SONAR, N_WHEELS
from robot_firmware.fpga.registers import Access, Field, Peripheral, Register

SYSTEM_ID = 0x5357_524D  # ASCII "SWRM"
IMAGE_VERSION_MAJOR = 1
IMAGE_VERSION_MINOR = 0
IMAGE_VERSION_PATCH = 0
IMAGE_BUILD_NUMBER = 1

ID = Register(
    name="ID",
    offset=0x00,
    access=Access.RO,
    reset=SYSTEM_ID,
    fields=(Field(name="ID", msb=31, lsb=0, doc="0x5357524D, ASCII 'SWRM'"),),
    doc="Fixed identifier of the swarm-robot FPGA image.",
)
VERSION = Register(
    name="VERSION",
    offset=0x04,
    access=Access.RO,
    reset=(IMAGE_VERSION_MAJOR << 24) | (IMAGE_VERSION_MINOR << 16) | IMAGE_VERSION_PATCH,
    fields=(
        Field(name="MAJOR", msb=31, lsb=24, doc="incompatible register map changes"),
        Field(name="MINOR", msb=23, lsb=16, doc="compatible additions"),
        Field(name="PATCH", msb=15, lsb=0, doc="fixes with no register map change"),
    ),
    doc="Register map version.",
)
VERSION_MAJOR = VERSION.field("MAJOR")
VERSION_MINOR = VERSION.field("MINOR")
VERSION_PATCH = VERSION.field("PATCH")
BUILD = Register(
    name="BUILD",
    offset=0x08,
    access=Access.RO,
    reset=IMAGE_BUILD_NUMBER,
    fields=(Field(name="BUILD", msb=31, lsb=0, doc="build number of the image"),),
    doc="Build number, increases with every image.",
)
CAPS = Register(
    name="CAPS",
    offset=0x0C,
    access=Access.RO,
    reset=N_WHEELS | (N_WHEELS << 4) | (DEFAULT_N_SONAR << 8),
    fields=(
        Field(name="N_QEP", msb=3, lsb=0, doc="encoder interfaces"),
        Field(name="N_PWM", msb=7, lsb=4, doc="PWM generators"),
        Field(name="N_SONAR", msb=12, lsb=8, doc="ultrasound rangers (reset shown for 12)"),
    ),
    doc="Instance counts of the image.",
)
CAPS_N_QEP = CAPS.field("N_QEP")
CAPS_N_PWM = CAPS.field("N_PWM")
CAPS_N_SONAR = CAPS.field("N_SONAR")
SCRATCH = Register(
    name="SCRATCH",
    offset=0x10,
    access=Access.RW,
    reset=0,
    fields=(Field(name="VALUE", msb=31, lsb=0, doc="any value; reads back what was written"),),
    doc="Scratch word for bus tests.",
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
        for handle, count in ((CAPS_N_QEP, n_qep), (CAPS_N_PWM, n_pwm), (CAPS_N_SONAR, n_sonar)):
            if not 0 <= count < (1 << handle.width):
                raise ValueError(f"{handle.field.name}={count} does not fit CAPS")
            caps = handle.insert(caps, count)
        super().__init__(name, tuple(CAPS.with_reset(caps) if r is CAPS else r for r in REGISTERS))

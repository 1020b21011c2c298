"""System probe: checks at boot that the FPGA image is the one the drivers were written for.

The firmware calls `identify` once before touching any other IP. It reads the System
ID block: ID must be 0x5357524D ('SWRM') and VERSION.MAJOR must equal
SUPPORTED_VERSION_MAJOR (a newer MINOR only adds registers, a PATCH changes none);
CAPS gives the number of encoder, PWM and sonar instances. Anything else raises
`IncompatibleFabricError`, the one exception a driver raises: driving motors through
a register map the drivers do not know is worse than not starting.

`wait_for_pll_lock` polls the clock block's STATUS.LOCKED after a reconfiguration,
letting time advance between polls through the `tick(dt_ns)` callback it is given
(the fabric's tick in the emulation, a sleep on hardware).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import clock as clock_map
from robot_firmware.fpga import sysid as sysid_map
from robot_firmware.fpga.address_map import CLOCK_BASE, SYSID_BASE
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.sysid import SYSTEM_ID

SUPPORTED_VERSION_MAJOR = 1
DEFAULT_LOCK_POLL_INTERVAL_NS = 1_000

_LOCKED = clock_map.STATUS_LOCKED.mask


class IncompatibleFabricError(RuntimeError):
    """The FPGA image is not one the drivers support (wrong ID or major version, or unreadable)."""


@dataclass(frozen=True)
class SystemInfo:
    """What the System ID block says about the FPGA image."""

    system_id: int
    version_major: int
    version_minor: int
    version_patch: int
    build: int
    n_qep: int
    n_pwm: int
    n_sonar: int

    @property
    def version(self) -> str:
        return f"{self.version_major}.{self.version_minor}.{self.version_patch}"


class SystemProbe:
    """Identification of the FPGA image and the PLL lock wait."""

    def __init__(self, bus: Bus) -> None:
        self._port = RegisterPort(bus)

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    def identify(self) -> SystemInfo:
        """Read ID, VERSION, BUILD and CAPS; raise IncompatibleFabricError if unsupported."""
        words: dict[str, int] = {}
        for register in (sysid_map.ID, sysid_map.VERSION, sysid_map.BUILD, sysid_map.CAPS):
            word = self._port.read(SYSID_BASE + register.offset)
            if word is None:
                raise IncompatibleFabricError(
                    f"System ID register {register.name} at "
                    f"{SYSID_BASE + register.offset:#010x} cannot be read"
                )
            words[register.name] = word
        if words["ID"] != SYSTEM_ID:
            raise IncompatibleFabricError(
                f"System ID {words['ID']:#010x} is not the swarm-robot image {SYSTEM_ID:#010x}"
            )
        version, caps = words["VERSION"], words["CAPS"]
        info = SystemInfo(
            system_id=words["ID"],
            version_major=sysid_map.VERSION_MAJOR.extract(version),
            version_minor=sysid_map.VERSION_MINOR.extract(version),
            version_patch=sysid_map.VERSION_PATCH.extract(version),
            build=words["BUILD"],
            n_qep=sysid_map.CAPS_N_QEP.extract(caps),
            n_pwm=sysid_map.CAPS_N_PWM.extract(caps),
            n_sonar=sysid_map.CAPS_N_SONAR.extract(caps),
        )
        if info.version_major != SUPPORTED_VERSION_MAJOR:
            raise IncompatibleFabricError(
                f"register map version {info.version} is not supported: "
                f"the drivers support major version {SUPPORTED_VERSION_MAJOR}"
            )
        return info

    def wait_for_pll_lock(
        self,
        tick: Callable[[int], None],
        timeout_ns: int,
        poll_interval_ns: int = DEFAULT_LOCK_POLL_INTERVAL_NS,
    ) -> bool:
        """Poll STATUS.LOCKED, calling `tick(dt_ns)` between polls, for up to `timeout_ns`.

        Returns whether the PLL locked. A refused read counts as not locked yet.
        """
        if poll_interval_ns <= 0:
            raise ValueError(f"poll interval must be positive: {poll_interval_ns} ns")
        waited_ns = 0
        while True:
            status = self._port.read(CLOCK_BASE + clock_map.STATUS.offset)
            if status is not None and status & _LOCKED:
                return True
            if waited_ns >= timeout_ns:
                return False
            step_ns = min(poll_interval_ns, timeout_ns - waited_ns)
            tick(step_ns)
            waited_ns += step_ns

"""Every register of a default fabric, by instance and address, for parametrised tests."""

from __future__ import annotations

from dataclasses import dataclass

from robot_firmware.fpga import Access, Fabric, Register


@dataclass(frozen=True)
class RegisterSite:
    """One register of one peripheral instance, at its absolute address."""

    peripheral: str
    register: Register
    address: int

    @property
    def id(self) -> str:
        return f"{self.peripheral}.{self.register.name}"


def register_sites(fabric: Fabric | None = None) -> list[RegisterSite]:
    fabric = fabric if fabric is not None else Fabric()
    return [
        RegisterSite(peripheral.name, reg, base + reg.offset)
        for base, peripheral in fabric.bus.mapped()
        for reg in peripheral.registers
    ]


ALL_SITES = register_sites()


def sites_with(*access: Access) -> list[RegisterSite]:
    return [site for site in ALL_SITES if site.register.access in access]


def read_ok(fabric: Fabric, peripheral: str, register: str) -> int:
    """Read a register through the bus, asserting the access succeeds."""
    result = fabric.bus.read(fabric.bus.address_of(peripheral, register))
    assert result.ok, result
    return result.value


def write_ok(fabric: Fabric, peripheral: str, register: str, value: int) -> None:
    """Write a register through the bus, asserting the access succeeds."""
    result = fabric.bus.write(fabric.bus.address_of(peripheral, register), value)
    assert result.ok, result

"""Access semantics over every declared register of every peripheral instance."""

from __future__ import annotations

import pytest

from robot_firmware.fpga import Access, BusErrorKind, Fabric, Field, Register
from robot_firmware.fpga.address_map import BRIDGE_BASE, BRIDGE_SPAN_BYTES, WINDOW_BYTES
from tests.fpga.register_sites import ALL_SITES, RegisterSite, sites_with

ALL_ONES = 0xFFFF_FFFF


def _ids(sites: list[RegisterSite]) -> list[str]:
    return [site.id for site in sites]


def _params(*access: Access) -> pytest.MarkDecorator:
    sites = sites_with(*access) if access else ALL_SITES
    return pytest.mark.parametrize("site", sites, ids=_ids(sites))


def test_catalog_covers_every_access_kind() -> None:
    kinds = {site.register.access for site in ALL_SITES}
    assert kinds == set(Access)


@_params(Access.RW, Access.RO, Access.W1C, Access.RC)
def test_readable_register_reads_its_reset_value(site: RegisterSite) -> None:
    fabric = Fabric()
    result = fabric.bus.read(site.address)
    assert result.ok
    assert result.value == site.register.reset


@_params(Access.WO)
def test_write_only_register_holds_its_reset_value(site: RegisterSite) -> None:
    assert Fabric().bus.peek(site.address) == site.register.reset


@_params(Access.RO, Access.RC)
def test_read_only_register_ignores_write_and_reports_error(site: RegisterSite) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    result = fabric.bus.write(site.address, ALL_ONES)
    assert result.error is BusErrorKind.WRITE_TO_READ_ONLY
    assert fabric.bus.snapshot() == before
    assert fabric.bus.error_counts[BusErrorKind.WRITE_TO_READ_ONLY] == 1
    assert fabric.bus.error_total == 1


@_params(Access.WO)
def test_write_only_register_read_reports_error(site: RegisterSite) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    result = fabric.bus.read(site.address)
    assert result.error is BusErrorKind.READ_OF_WRITE_ONLY
    assert result.value == 0
    assert fabric.bus.snapshot() == before
    assert fabric.bus.error_counts[BusErrorKind.READ_OF_WRITE_ONLY] == 1


@_params(Access.RW)
def test_read_write_register_reads_back_what_was_written(site: RegisterSite) -> None:
    fabric = Fabric()
    pattern = 0xA5A5_5A5A & site.register.mask
    assert fabric.bus.write(site.address, pattern).ok
    assert fabric.bus.read(site.address).value == pattern


@_params(Access.W1C)
def test_write_one_to_clear_register_clears_only_the_written_ones(site: RegisterSite) -> None:
    fabric = Fabric()
    peripheral = fabric.bus.decode(site.address)
    assert peripheral is not None
    mask = site.register.mask
    peripheral.peripheral.hw_force(site.register.offset, mask)
    assert fabric.bus.write(site.address, 0).ok
    assert fabric.bus.read(site.address).value == mask
    assert fabric.bus.write(site.address, 0x5555_5555).ok
    assert fabric.bus.read(site.address).value == mask & ~0x5555_5555
    assert fabric.bus.write(site.address, ALL_ONES).ok
    assert fabric.bus.read(site.address).value == 0


@_params(Access.RC)
def test_read_to_clear_register_clears_on_read(site: RegisterSite) -> None:
    fabric = Fabric()
    decoded = fabric.bus.decode(site.address)
    assert decoded is not None
    decoded.peripheral.hw_force(site.register.offset, site.register.mask)
    assert fabric.bus.peek(site.address) == site.register.mask
    assert fabric.bus.read(site.address).value == site.register.mask
    assert fabric.bus.read(site.address).value == 0


@_params(Access.RW, Access.W1C, Access.WO)
def test_reserved_bits_read_zero_after_writing_all_ones(site: RegisterSite) -> None:
    fabric = Fabric()
    assert fabric.bus.write(site.address, ALL_ONES).ok
    stored = fabric.bus.peek(site.address)
    assert stored is not None
    assert stored & ~site.register.mask == 0
    if site.register.access.readable:
        assert fabric.bus.read(site.address).value & ~site.register.mask == 0


@_params(Access.RO, Access.RC)
def test_reserved_bits_read_zero_even_when_hardware_drives_them(site: RegisterSite) -> None:
    fabric = Fabric()
    decoded = fabric.bus.decode(site.address)
    assert decoded is not None
    decoded.peripheral.hw_force(site.register.offset, ALL_ONES)
    assert fabric.bus.read(site.address).value == site.register.mask


@_params()
def test_misaligned_access_errors_and_changes_nothing(site: RegisterSite) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    for misalignment in (1, 2, 3):
        address = site.address + misalignment
        assert fabric.bus.read(address).error is BusErrorKind.MISALIGNED
        assert fabric.bus.write(address, ALL_ONES).error is BusErrorKind.MISALIGNED
    assert fabric.bus.snapshot() == before
    assert fabric.bus.error_counts[BusErrorKind.MISALIGNED] == 6
    assert fabric.bus.error_total == 6


@_params(Access.RW, Access.W1C, Access.WO)
def test_write_of_value_outside_32_bits_errors_and_changes_nothing(site: RegisterSite) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    for value in (-1, 1 << 32, (1 << 40) + 1):
        assert fabric.bus.write(site.address, value).error is BusErrorKind.VALUE_OUT_OF_RANGE
    assert fabric.bus.snapshot() == before
    assert fabric.bus.error_counts[BusErrorKind.VALUE_OUT_OF_RANGE] == 3


def _unmapped_addresses() -> list[int]:
    fabric = Fabric()
    addresses = [
        0,
        BRIDGE_BASE - 4,
        BRIDGE_BASE + BRIDGE_SPAN_BYTES,
        BRIDGE_BASE + 0x0E00,  # an empty window between the filters and the sonars
        BRIDGE_BASE + 0x1F00,  # past the last sonar of the default configuration
        0xFFFF_FFFC,
        1 << 40,
        -4,
    ]
    for base, peripheral in fabric.bus.mapped():
        last = max(reg.offset for reg in peripheral.registers)
        addresses += [base + last + 4, base + WINDOW_BYTES - 4]
    return addresses


@pytest.mark.parametrize("address", _unmapped_addresses(), ids=lambda a: f"{a:#x}")
def test_unmapped_address_errors_and_changes_nothing(address: int) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    read = fabric.bus.read(address)
    assert read.error is BusErrorKind.UNMAPPED
    assert read.value == 0
    assert fabric.bus.write(address, 1).error is BusErrorKind.UNMAPPED
    assert fabric.bus.snapshot() == before
    assert fabric.bus.error_counts[BusErrorKind.UNMAPPED] == 2


def test_error_counters_count_each_kind_separately() -> None:
    fabric = Fabric()
    bus = fabric.bus
    id_address = bus.address_of("sysid", "ID")
    kick_address = bus.address_of("watchdog", "KICK")
    bus.read(BRIDGE_BASE + 0x0E00)
    bus.read(id_address + 2)
    bus.read(id_address + 1)
    bus.write(id_address, 1)
    bus.write(id_address, 2)
    bus.write(id_address, 3)
    bus.read(kick_address)
    bus.write(bus.address_of("sysid", "SCRATCH"), -5)
    assert bus.error_counts == {
        BusErrorKind.UNMAPPED: 1,
        BusErrorKind.MISALIGNED: 2,
        BusErrorKind.WRITE_TO_READ_ONLY: 3,
        BusErrorKind.READ_OF_WRITE_ONLY: 1,
        BusErrorKind.VALUE_OUT_OF_RANGE: 1,
    }
    assert bus.error_total == 8
    assert bus.read_count == 4
    assert bus.write_count == 4


def test_declaration_with_overlapping_fields_is_refused() -> None:
    with pytest.raises(ValueError, match="overlaps"):
        Register("BAD", 0x00, Access.RW, 0, (Field("A", 3, 0, ""), Field("B", 4, 3, "")), "")


def test_declaration_with_reset_in_reserved_bits_is_refused() -> None:
    with pytest.raises(ValueError, match="reserved"):
        Register("BAD", 0x00, Access.RW, 0x10, (Field("A", 3, 0, ""),), "")


@pytest.mark.parametrize("offset", [0x02, -4, WINDOW_BYTES])
def test_declaration_outside_a_word_slot_is_refused(offset: int) -> None:
    with pytest.raises(ValueError, match="word slot"):
        Register("BAD", offset, Access.RW, 0, (Field("A", 3, 0, ""),), "")


def test_declaration_with_bits_beyond_32_is_refused() -> None:
    with pytest.raises(ValueError, match="bit range"):
        Field("A", 32, 0, "")

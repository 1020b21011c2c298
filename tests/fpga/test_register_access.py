"""Access semantics over every declared register of every peripheral instance, and the
rules of the declarations themselves (keyword-only, field handles resolved at import)."""

from __future__ import annotations

from types import ModuleType

import pytest

from robot_firmware.fpga import (
    Access,
    BusErrorKind,
    Fabric,
    Field,
    FieldHandle,
    Register,
    clock,
    digital_filter,
    positioning,
    pwm,
    qep,
    sonar,
    sysid,
    watchdog,
)
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
        Register(
            name="BAD",
            offset=0x00,
            access=Access.RW,
            reset=0,
            fields=(Field(name="A", msb=3, lsb=0, doc=""), Field(name="B", msb=4, lsb=3, doc="")),
            doc="",
        )


def test_declaration_with_reset_in_reserved_bits_is_refused() -> None:
    with pytest.raises(ValueError, match="reserved"):
        Register(
            name="BAD",
            offset=0x00,
            access=Access.RW,
            reset=0x10,
            fields=(Field(name="A", msb=3, lsb=0, doc=""),),
            doc="",
        )


@pytest.mark.parametrize("offset", [0x02, -4, WINDOW_BYTES])
def test_declaration_outside_a_word_slot_is_refused(offset: int) -> None:
    with pytest.raises(ValueError, match="word slot"):
        Register(
            name="BAD",
            offset=offset,
            access=Access.RW,
            reset=0,
            fields=(Field(name="A", msb=3, lsb=0, doc=""),),
            doc="",
        )


def test_declaration_with_bits_beyond_32_is_refused() -> None:
    with pytest.raises(ValueError, match="bit range"):
        Field(name="A", msb=32, lsb=0, doc="")


def _ctrl_register() -> Register:
    return Register(
        name="CTRL",
        offset=0x08,
        access=Access.RW,
        reset=0,
        fields=(
            Field(name="EN", msb=0, lsb=0, doc="enable"),
            Field(name="GAIN", msb=7, lsb=4, doc="gain"),
        ),
        doc="Control.",
    )


def test_positional_register_declaration_is_refused() -> None:
    en = Field(name="EN", msb=0, lsb=0, doc="enable")
    with pytest.raises(TypeError, match="positional"):
        Register("CTRL", 0x00, Access.RW, 0, (en,), "Control.")  # type: ignore[call-arg]


def test_positional_field_declaration_is_refused() -> None:
    with pytest.raises(TypeError, match="positional"):
        Field("EN", 0, 0, "enable")  # type: ignore[call-arg]


def test_handle_of_an_unknown_field_is_refused_where_it_is_declared() -> None:
    ctrl = _ctrl_register()
    with pytest.raises(KeyError, match=r"CTRL has no field ENABLE \(fields: EN, GAIN\)"):
        ctrl.field("ENABLE")


def test_handle_of_a_field_from_another_register_is_refused() -> None:
    stray = Field(name="EN", msb=0, lsb=0, doc="enable")
    with pytest.raises(ValueError, match="not a field of CTRL"):
        FieldHandle(register=_ctrl_register(), field=stray)


def test_field_handle_knows_its_register_mask_and_shift() -> None:
    ctrl = _ctrl_register()
    gain = ctrl.field("GAIN")
    assert gain.register is ctrl
    assert gain.field is ctrl.fields[1]
    assert gain.name == "CTRL.GAIN"
    assert (gain.offset, gain.mask, gain.shift, gain.width) == (0x08, 0xF0, 4, 4)
    assert gain.extract(0xFFFF_FF5F) == 0x5
    assert gain.insert(0xFFFF_FFFF, 0x3) == 0xFFFF_FF3F
    assert gain.insert(0, 0x13) == 0x30  # truncated to the field width


IP_MODULES = (clock, digital_filter, positioning, pwm, qep, sonar, sysid, watchdog)


def _handles(module: ModuleType) -> list[tuple[str, FieldHandle]]:
    return [(name, v) for name, v in vars(module).items() if isinstance(v, FieldHandle)]


@pytest.mark.parametrize("module", IP_MODULES, ids=lambda m: m.__name__.rsplit(".", 1)[-1])
def test_field_handles_of_an_ip_are_named_for_and_bound_to_its_own_registers(
    module: ModuleType,
) -> None:
    handles = _handles(module)
    assert handles, f"{module.__name__} declares no field handles"
    for name, handle in handles:
        assert any(handle.register is reg for reg in module.REGISTERS), name
        assert name == f"{handle.register.name}_{handle.field.name}"
        assert handle.mask == handle.field.mask
        assert handle.shift == handle.field.lsb

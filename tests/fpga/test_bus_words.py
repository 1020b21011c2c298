"""The drivers' word accesses (`read_word`, `write_word`) against the full `read` and `write`:
the same values, refusals, counts, side effects and stored bits, first time and again (when
the address is remembered)."""

from __future__ import annotations

import numpy as np
import pytest

from robot_firmware.fpga import Bus, BusErrorKind, Fabric, RecordingBus, sysid
from robot_firmware.fpga.address_map import BRIDGE_BASE, SYSID_BASE
from tests.fpga.register_sites import ALL_SITES, RegisterSite

PATTERNS = (0xFFFF_FFFF, 0x5555_5555, 0, 0xA5A5_A5A5)


@pytest.mark.parametrize("site", ALL_SITES, ids=[site.id for site in ALL_SITES])
def test_word_accesses_match_full_accesses_on_every_register(site: RegisterSite) -> None:
    by_result, by_word = Fabric(), Fabric()
    for pattern in PATTERNS:
        for _ in range(2):  # the second access of each kind takes the remembered address
            written = by_result.bus.write(site.address, pattern)
            assert by_word.bus.write_word(site.address, pattern) is written.ok
            read = by_result.bus.read(site.address)
            assert by_word.bus.read_word(site.address) == (read.value if read.ok else None)
            assert by_word.bus.snapshot() == by_result.bus.snapshot()
    for counter in ("read_count", "write_count", "error_counts"):
        assert getattr(by_word.bus, counter) == getattr(by_result.bus, counter)


@pytest.mark.parametrize(
    ("address", "value", "kind"),
    [
        (SYSID_BASE + sysid.SCRATCH.offset + 2, 1, BusErrorKind.MISALIGNED),
        (BRIDGE_BASE + 0x0E00, 1, BusErrorKind.UNMAPPED),
        (SYSID_BASE + sysid.SCRATCH.offset, -5, BusErrorKind.VALUE_OUT_OF_RANGE),
        (SYSID_BASE + sysid.SCRATCH.offset, 2**32, BusErrorKind.VALUE_OUT_OF_RANGE),
        (SYSID_BASE + sysid.SCRATCH.offset, 1.0, BusErrorKind.VALUE_OUT_OF_RANGE),
        (SYSID_BASE + sysid.ID.offset, 1, BusErrorKind.WRITE_TO_READ_ONLY),
    ],
)
def test_refused_word_write_changes_nothing_even_after_a_good_one(
    address: int, value: object, kind: BusErrorKind
) -> None:
    fabric = Fabric()
    bus = fabric.bus
    assert bus.write_word(SYSID_BASE + sysid.SCRATCH.offset, 7)  # remembered
    before = bus.snapshot()
    assert bus.write_word(address, value) is False  # type: ignore[arg-type]
    assert bus.snapshot() == before
    assert bus.error_counts[kind] == 1


def test_a_float_address_equal_to_a_remembered_one_is_refused() -> None:
    bus = Fabric().bus
    address = SYSID_BASE + sysid.SCRATCH.offset
    assert bus.write_word(address, 3) and bus.read_word(address) == 3
    assert bus.read_word(float(address)) is None  # type: ignore[arg-type]
    assert bus.write_word(float(address), 4) is False  # type: ignore[arg-type]
    assert bus.read_word(address) == 3
    assert bus.error_counts[BusErrorKind.UNMAPPED] == 2


def test_numpy_integer_address_and_value_work_as_with_write() -> None:
    bus = Fabric().bus
    address = SYSID_BASE + sysid.SCRATCH.offset
    assert bus.write_word(np.uint32(address), np.uint32(9))  # type: ignore[arg-type]
    assert bus.read_word(np.int64(address)) == 9  # type: ignore[arg-type]
    assert bus.error_total == 0


def test_recording_bus_records_word_accesses() -> None:
    fabric = Fabric(bus=RecordingBus())
    bus = fabric.bus
    assert isinstance(bus, RecordingBus)
    address = SYSID_BASE + sysid.SCRATCH.offset
    for value in (1, 2):
        assert bus.write_word(address, value)
        assert bus.read_word(address) == value
    assert [(a.op.value, a.value) for a in bus.accesses] == [
        ("write", 1),
        ("read", 1),
        ("write", 2),
        ("read", 2),
    ]


def test_a_subclass_overriding_read_and_write_sees_every_word_access() -> None:
    class CountingBus(Bus):
        def __init__(self) -> None:
            super().__init__()
            self.seen = 0

        def read(self, address: int):  # type: ignore[no-untyped-def]
            self.seen += 1
            return super().read(address)

        def write(self, address: int, value: int):  # type: ignore[no-untyped-def]
            self.seen += 1
            return super().write(address, value)

    bus = Fabric(bus=CountingBus()).bus
    assert isinstance(bus, CountingBus)
    address = SYSID_BASE + sysid.SCRATCH.offset
    for _ in range(3):
        bus.write_word(address, 5)
        bus.read_word(address)
    assert bus.seen == 6

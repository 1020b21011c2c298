"""The bus: dispatch by address, error results instead of exceptions, logging, recording."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from robot_firmware.fpga import (
    Bus,
    BusAccess,
    BusErrorKind,
    BusOp,
    Fabric,
    RecordingBus,
    RegisterAccessError,
    sonar,
    sysid,
)
from robot_firmware.fpga.address_map import BRIDGE_BASE, SYSID_BASE
from robot_firmware.fpga.sysid import SystemId


def test_bus_dispatches_by_absolute_address() -> None:
    fabric = Fabric()
    assert fabric.bus.read(SYSID_BASE + sysid.ID.offset).value == sysid.SYSTEM_ID
    assert fabric.bus.address_of("sysid", "SCRATCH") == SYSID_BASE + sysid.SCRATCH.offset
    assert fabric.bus.write(SYSID_BASE + sysid.SCRATCH.offset, 0xDEAD_BEEF).ok
    assert fabric.sysid.peek(sysid.SCRATCH.offset) == 0xDEAD_BEEF


def test_same_register_in_two_instances_is_independent() -> None:
    fabric = Fabric()
    bus = fabric.bus
    assert bus.write(bus.address_of("pwm1", "DUTY_TICKS"), 100).ok
    assert bus.read(bus.address_of("pwm1", "DUTY_TICKS")).value == 100
    assert bus.read(bus.address_of("pwm0", "DUTY_TICKS")).value == 0


def test_numpy_integers_are_accepted_as_address_and_value() -> None:
    fabric = Fabric()
    address = np.uint32(fabric.bus.address_of("sysid", "SCRATCH"))
    assert fabric.bus.write(address, np.uint32(7)).ok  # type: ignore[arg-type]
    assert fabric.bus.read(address).value == 7  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [1.5, "0xff200000", None, float("nan")])
def test_non_integer_address_or_value_is_a_bus_error(bad: object) -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    assert fabric.bus.read(bad).error is BusErrorKind.UNMAPPED  # type: ignore[arg-type]
    scratch = fabric.bus.address_of("sysid", "SCRATCH")
    result = fabric.bus.write(scratch, bad)  # type: ignore[arg-type]
    assert result.error is BusErrorKind.VALUE_OUT_OF_RANGE
    assert fabric.bus.snapshot() == before


def test_mapping_two_peripherals_at_one_base_is_refused() -> None:
    bus = Bus()
    bus.map(BRIDGE_BASE, SystemId())
    with pytest.raises(ValueError, match="already holds"):
        bus.map(BRIDGE_BASE, SystemId("other"))
    with pytest.raises(ValueError, match="aligned"):
        bus.map(BRIDGE_BASE + 0x80, SystemId("third"))


def test_peripheral_called_directly_with_an_illegal_access_raises() -> None:
    peripheral = SystemId()
    with pytest.raises(RegisterAccessError):
        peripheral.write(sysid.ID.offset, 1)
    with pytest.raises(RegisterAccessError):
        peripheral.read(0x80)
    with pytest.raises(RegisterAccessError):
        peripheral.write(sysid.SCRATCH.offset, 1 << 32)


def test_bus_errors_are_logged_with_rate_limit(caplog: pytest.LogCaptureFixture) -> None:
    fabric = Fabric()
    unmapped = BRIDGE_BASE + 0x0E00
    with caplog.at_level(logging.DEBUG, logger="robot_firmware.fpga.bus"):
        for _ in range(100):
            fabric.bus.read(unmapped)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    debugs = [r for r in caplog.records if r.levelno == logging.DEBUG]
    assert len(warnings) == 3  # the 1st, 10th and 100th
    assert len(debugs) == 97
    assert "unmapped" in warnings[0].getMessage()
    assert f"{unmapped:#010x}" in warnings[0].getMessage()


def test_recording_bus_records_every_access_in_order() -> None:
    bus = RecordingBus()
    fabric = Fabric(bus=bus)
    scratch = bus.address_of("sysid", "SCRATCH")
    bus.write(scratch, 42)
    bus.read(scratch)
    bus.read(scratch + 1)
    assert bus.accesses == [
        BusAccess(BusOp.WRITE, scratch, 42),
        BusAccess(BusOp.READ, scratch, 42),
        BusAccess(BusOp.READ, scratch + 1, 0, BusErrorKind.MISALIGNED),
    ]
    assert bus.writes() == [BusAccess(BusOp.WRITE, scratch, 42)]
    bus.clear()
    assert bus.accesses == []
    assert fabric.bus is bus


def test_peek_has_no_read_side_effect() -> None:
    fabric = Fabric()
    events = fabric.bus.address_of("sonar0", "EVENTS")
    fabric.sonar[0].hw_force(sonar.EVENTS.offset, 0b1)
    assert fabric.bus.peek(events) == 1
    assert fabric.bus.peek(events) == 1
    assert fabric.bus.peek(BRIDGE_BASE + 0x0E00) is None
    assert fabric.bus.read_count == 0

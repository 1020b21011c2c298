"""Positioning driver: each new valid fix is read once and consistently; a cut fix gives None."""

from __future__ import annotations

import math

import pytest

from robot_firmware.drivers.positioning import MAX_READ_ATTEMPTS, PoseFix, PositioningDriver
from robot_firmware.fpga import BusResult, Fabric, PositionFix, RecordingBus

MS = 1_000_000


def deliver(fabric: Fabric, fix: PositionFix) -> None:
    fabric.hw_apply_sense([0, 0, 0, 0], [None] * len(fabric.sonar), fix)


class FixDuringReadBus(RecordingBus):
    """A bus on which the tracker delivers a new fix while the pose registers are being read."""

    def __init__(self, deliveries: int) -> None:
        super().__init__()
        self.fabric = Fabric(bus=self)
        self.deliveries_left = deliveries
        self.stamp_ns = 100
        self._y_address = self.address_of("positioning", "Y_UM")

    def read(self, address: int) -> BusResult:
        result = super().read(address)
        if address == self._y_address and self.deliveries_left > 0:
            self.deliveries_left -= 1
            self.stamp_ns += 1
            deliver(self.fabric, PositionFix(float(self.stamp_ns), -1.0, 0.5, self.stamp_ns))
        return result


def test_fix_is_read_once_then_none_until_the_next_one() -> None:
    fabric = Fabric()
    positioning = PositioningDriver(fabric.bus)
    assert positioning.read_fix() is None  # nothing received yet
    deliver(fabric, PositionFix(1.25, -0.5, -math.pi / 2, stamp_ns=1))
    fix = positioning.read_fix()
    assert isinstance(fix, PoseFix)
    assert (fix.x_m, fix.y_m, fix.sequence) == (1.25, -0.5, 1)
    assert fix.heading_rad == pytest.approx(-math.pi / 2, abs=1e-6)  # microradian steps
    assert positioning.read_fix() is None
    deliver(fabric, PositionFix(1.25, -0.5, -math.pi / 2, stamp_ns=1))  # the same fix again
    assert positioning.read_fix() is None
    deliver(fabric, PositionFix(2.0, 3.0, 3.0, stamp_ns=2))
    second = positioning.read_fix()
    assert second is not None
    assert (second.x_m, second.y_m, second.sequence) == (2.0, 3.0, 2)
    assert positioning.bus_errors == 0


def test_fix_with_nothing_new_costs_one_read() -> None:
    bus = RecordingBus()
    fabric = Fabric(bus=bus)
    positioning = PositioningDriver(bus)
    deliver(fabric, PositionFix(1.0, 1.0, 0.0, stamp_ns=1))
    positioning.read_fix()
    bus.clear()
    assert positioning.read_fix() is None
    assert [a.address for a in bus.accesses] == [bus.address_of("positioning", "SEQ")]


def test_invalid_or_cut_fix_gives_none() -> None:
    fabric = Fabric()
    positioning = PositioningDriver(fabric.bus)
    deliver(fabric, PositionFix(1.0, 1.0, 0.0, stamp_ns=1))
    fabric.positioning.hw_cut_fix()
    assert positioning.read_fix() is None
    deliver(fabric, PositionFix(2.0, 2.0, 0.0, stamp_ns=2, valid=False))
    assert positioning.read_fix() is None
    deliver(fabric, PositionFix(3.0, 3.0, 0.0, stamp_ns=3))
    fix = positioning.read_fix()
    assert fix is not None
    assert fix.x_m == 3.0


def test_stale_fix_gives_none() -> None:
    fabric = Fabric()
    positioning = PositioningDriver(fabric.bus)
    deliver(fabric, PositionFix(1.0, 1.0, 0.0, stamp_ns=1))
    fabric.tick(600 * MS)  # STALE_MS is 500 at reset
    assert positioning.read_fix() is None


def test_fix_arriving_during_the_read_is_retried_and_read_consistently() -> None:
    bus = FixDuringReadBus(deliveries=1)
    positioning = PositioningDriver(bus)
    fix = positioning.read_fix()
    assert fix is not None
    assert fix.sequence == 1
    assert (fix.x_m, fix.y_m, fix.heading_rad) == (101.0, -1.0, 0.5)
    assert positioning.torn_reads == 1


def test_read_gives_up_after_bounded_retries_and_succeeds_later() -> None:
    bus = FixDuringReadBus(deliveries=MAX_READ_ATTEMPTS)
    positioning = PositioningDriver(bus)
    assert positioning.read_fix() is None
    assert positioning.torn_reads == MAX_READ_ATTEMPTS
    fix = positioning.read_fix()
    assert fix is not None
    assert fix.sequence == MAX_READ_ATTEMPTS
    assert fix.x_m == 100.0 + MAX_READ_ATTEMPTS

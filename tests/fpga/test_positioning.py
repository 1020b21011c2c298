"""Indoor positioning receiver: fixes in micrometres and microradians, sequence, validity."""

from __future__ import annotations

import math

from robot_firmware.fpga import Fabric, PositionFix, as_signed32
from robot_firmware.fpga.positioning import wrap_angle_rad
from tests.fpga.register_sites import read_ok, write_ok

MS = 1_000_000
NEW_FIX, LOST = 0b01, 0b10


def deliver(fabric: Fabric, fix: PositionFix | None) -> None:
    fabric.hw_apply_sense([0, 0, 0, 0], [None] * len(fabric.sonar), fix)


def pose(fabric: Fabric) -> tuple[int, int, int]:
    return (
        as_signed32(read_ok(fabric, "positioning", "X_UM")),
        as_signed32(read_ok(fabric, "positioning", "Y_UM")),
        as_signed32(read_ok(fabric, "positioning", "HEADING_URAD")),
    )


def test_fix_appears_in_signed_micrometres_and_microradians() -> None:
    fabric = Fabric()
    assert read_ok(fabric, "positioning", "STATUS") == 0
    deliver(fabric, PositionFix(1.2345678, -0.5, -math.pi / 2, stamp_ns=1))
    assert pose(fabric) == (1_234_568, -500_000, -1_570_796)
    assert read_ok(fabric, "positioning", "STATUS") == 1
    assert read_ok(fabric, "positioning", "SEQ") == 1
    assert read_ok(fabric, "positioning", "EVENTS") == NEW_FIX
    assert read_ok(fabric, "positioning", "EVENTS") == 0
    assert read_ok(fabric, "positioning", "AGE_MS") == 0


def test_sequence_counts_new_fixes_only() -> None:
    fabric = Fabric()
    for stamp_ns in (10, 10, 10, 20, 20, 30):
        deliver(fabric, PositionFix(0.0, 0.0, 0.0, stamp_ns))
    deliver(fabric, None)
    assert read_ok(fabric, "positioning", "SEQ") == 3


def test_world_can_cut_the_fix_and_the_last_pose_stays() -> None:
    fabric = Fabric()
    deliver(fabric, PositionFix(0.25, 0.5, 1.0, stamp_ns=1))
    read_ok(fabric, "positioning", "EVENTS")
    deliver(fabric, PositionFix(9.0, 9.0, 0.0, stamp_ns=2, valid=False))
    assert read_ok(fabric, "positioning", "STATUS") == 0
    assert read_ok(fabric, "positioning", "EVENTS") == LOST
    assert pose(fabric) == (250_000, 500_000, 1_000_000)
    deliver(fabric, PositionFix(0.3, 0.5, 1.0, stamp_ns=3))
    assert read_ok(fabric, "positioning", "STATUS") == 1
    fabric.positioning.hw_cut_fix()
    assert read_ok(fabric, "positioning", "STATUS") == 0


def test_fix_goes_stale_without_updates() -> None:
    fabric = Fabric()
    write_ok(fabric, "positioning", "STALE_MS", 200)
    deliver(fabric, PositionFix(0.0, 0.0, 0.0, stamp_ns=1))
    fabric.tick(199 * MS)
    assert read_ok(fabric, "positioning", "STATUS") == 1
    assert read_ok(fabric, "positioning", "AGE_MS") == 199
    fabric.tick(1 * MS)
    assert read_ok(fabric, "positioning", "STATUS") == 0
    assert read_ok(fabric, "positioning", "EVENTS") == NEW_FIX | LOST


def test_non_finite_fix_is_rejected_and_counted() -> None:
    fabric = Fabric()
    deliver(fabric, PositionFix(float("nan"), 0.0, 0.0, stamp_ns=1))
    assert read_ok(fabric, "positioning", "REJECTED") == 1
    assert read_ok(fabric, "positioning", "SEQ") == 0
    assert read_ok(fabric, "positioning", "STATUS") == 0


def test_heading_is_wrapped_and_position_saturates() -> None:
    fabric = Fabric()
    deliver(fabric, PositionFix(1e9, -1e9, 3 * math.pi, stamp_ns=1))
    assert pose(fabric) == (2**31 - 1, -(2**31), 3_141_593)
    assert wrap_angle_rad(-math.pi) == math.pi
    assert wrap_angle_rad(2 * math.pi + 0.5) == 0.5


def test_huge_finite_fix_saturates_instead_of_overflowing() -> None:
    from robot_firmware.fpga.positioning import _saturate_int32

    assert _saturate_int32(1e300 * 1e6) == 2**31 - 1
    assert _saturate_int32(-1e300 * 1e6) == -(2**31)


def test_the_scenarios_positioning_range_is_where_the_fix_saturates() -> None:
    """swarm_config's POSITIONING_RANGE_M, the bound of every scenario, is this IP's."""
    from swarm_config.sensors import POSITIONING_RANGE_M

    fabric = Fabric()
    deliver(fabric, PositionFix(POSITIONING_RANGE_M, -POSITIONING_RANGE_M, 0.0, stamp_ns=1))
    inside = pose(fabric)[:2]
    assert inside == (2**31 - 1, -(2**31 - 1))
    deliver(fabric, PositionFix(POSITIONING_RANGE_M - 1e-3, 0.0, 0.0, stamp_ns=2))
    assert pose(fabric)[0] == 2**31 - 1 - 1000  # a millimetre inside is not saturated

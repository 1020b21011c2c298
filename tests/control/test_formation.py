"""Formation geometry, eqs. 17-21 with DESIGN.md §6's corrected eq. 20, against hand-worked cases.

Conventions of the hand calculations below: a pose is (x, y, θ); R(θ) rotates by θ, so
R(θ)·(x, y) = (x·cosθ − y·sinθ, x·sinθ + y·cosθ); a world point p is seen from a follower F as
R(−θ_F)·(p − p_F) = (Δx·cosθ_F + Δy·sinθ_F, −Δx·sinθ_F + Δy·cosθ_F).  √2/2 ≈ 0.70711.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from robot_firmware.control.formation import (
    follower_frame_to_world,
    follower_reference,
    follower_slot_in_follower_frame,
    follower_slot_in_world,
    slot_in_leader_frame,
)

PI = math.pi
HALF_SQRT2 = math.sqrt(2.0) / 2.0


@dataclass(frozen=True)
class FormationCase:
    """One leader/follower geometry worked out by hand."""

    leader_pose: tuple[float, float, float]
    follower_pose: tuple[float, float, float]
    slot_distance_m: float
    slot_angle_rad: float
    slot_in_leader_m: tuple[float, float]  # eq. 17
    slot_in_world_m: tuple[float, float]
    leader_in_follower_m: tuple[float, float]  # eq. 18
    slot_in_follower_m: tuple[float, float]  # eq. 19
    desired_heading_rad: float
    slot_rate: tuple[float, float, float]  # for LEADER_RATE


# (ẋ, ẏ, θ̇) of the leader in every case: the slot moves at ṗ_L + θ̇_L·(−arm_y, arm_x), with
# arm = world slot − leader position, and turns at θ̇_L.
LEADER_RATE = (0.1, 0.2, 0.5)

CASES = {
    # Leader north-east of the follower (Δ = L − F = (0.4, 0.3): θ_mF = atan2(0.3, 0.4) ≈ 0.6435
    # in quadrant I, where eq. 20 as printed, atan(Δx/Δy) ≈ 0.9273, is off already).
    # Eq. 17: slot 0.5 m at π, (x_DL, y_DL) = (−0.5, 0). Leader heading 0, so the world slot is
    # (1.0 − 0.5, 2.0) = (0.5, 2.0). From the follower at (0.6, 1.7) heading π/2:
    # Δ = (−0.1, 0.3) → (Δx·0 + Δy·1, −Δx·1 + Δy·0) = (0.3, 0.1).
    # Eq. 18, the leader from the follower: (0.4, 0.3) → (0.3, −0.4).
    # Rate: arm = (0.5, 2.0) − (1.0, 2.0) = (−0.5, 0) → (0.1 − 0, 0.2 + 0.5·(−0.5), 0.5).
    "leader_in_quadrant_1": FormationCase(
        leader_pose=(1.0, 2.0, 0.0),
        follower_pose=(0.6, 1.7, PI / 2),
        slot_distance_m=0.5,
        slot_angle_rad=PI,
        slot_in_leader_m=(-0.5, 0.0),
        slot_in_world_m=(0.5, 2.0),
        leader_in_follower_m=(0.3, -0.4),
        slot_in_follower_m=(0.3, 0.1),
        desired_heading_rad=0.0,
        slot_rate=(0.1, -0.05, 0.5),
    ),
    # Leader north-west (Δ = (−0.4, 0.3), θ_mF ≈ 2.4981 in quadrant II).
    # Eq. 17: slot 0.5 m at −π/2 (the leader's right), (0, −0.5). Leader heading π/2:
    # R(π/2)·(0, −0.5) = (0.5, 0), world slot (−0.4 + 0.5, 0.3) = (0.1, 0.3).
    # Follower at the origin heading π: Δ = (0.1, 0.3) → (−Δx, −Δy) = (−0.1, −0.3).
    # Eq. 18: (−0.4, 0.3) → (0.4, −0.3).
    # Rate: arm = (0.5, 0) → (0.1 − 0, 0.2 + 0.5·0.5, 0.5) = (0.1, 0.45, 0.5).
    "leader_in_quadrant_2": FormationCase(
        leader_pose=(-0.4, 0.3, PI / 2),
        follower_pose=(0.0, 0.0, PI),
        slot_distance_m=0.5,
        slot_angle_rad=-PI / 2,
        slot_in_leader_m=(0.0, -0.5),
        slot_in_world_m=(0.1, 0.3),
        leader_in_follower_m=(0.4, -0.3),
        slot_in_follower_m=(-0.1, -0.3),
        desired_heading_rad=PI / 2,
        slot_rate=(0.1, 0.45, 0.5),
    ),
    # Leader south-west (Δ = (−0.4, −0.3), θ_mF ≈ −2.4981 in quadrant III).
    # Eq. 17: slot 0.5 m at 3π/4, 0.5·(−√2/2, √2/2) = (−0.35355, 0.35355). Leader heading −3π/4:
    # the slot points along 3π/4 − 3π/4 = 0, world offset (0.5, 0), world slot (0.1, −0.3).
    # Follower at the origin heading −π/2: Δ = (0.1, −0.3) → (−Δy, Δx) = (0.3, 0.1).
    # Eq. 18: (−0.4, −0.3) → (0.3, −0.4).
    # Rate: arm = (0.5, 0) → (0.1, 0.45, 0.5).
    "leader_in_quadrant_3": FormationCase(
        leader_pose=(-0.4, -0.3, -3 * PI / 4),
        follower_pose=(0.0, 0.0, -PI / 2),
        slot_distance_m=0.5,
        slot_angle_rad=3 * PI / 4,
        slot_in_leader_m=(-0.5 * HALF_SQRT2, 0.5 * HALF_SQRT2),
        slot_in_world_m=(0.1, -0.3),
        leader_in_follower_m=(0.3, -0.4),
        slot_in_follower_m=(0.3, 0.1),
        desired_heading_rad=-3 * PI / 4,
        slot_rate=(0.1, 0.45, 0.5),
    ),
    # Leader south-east (Δ = (0.4, −0.3), θ_mF ≈ −0.6435 in quadrant IV); the headings sit on
    # either side of ±π: leader 3π/4, follower −3π/4, so θ_F − θ_L = −3π/2 wraps to φ = π/2.
    # Eq. 17: slot 0.5 m at 3π/4, (−0.35355, 0.35355); in the world it points along
    # 3π/4 + 3π/4 = 3π/2 ≡ −π/2: offset (0, −0.5), world slot (0.4, −0.8).
    # Follower at the origin heading −3π/4 (cos = sin = −√2/2): Δ = (0.4, −0.8) →
    # (0.4·(−√2/2) + (−0.8)·(−√2/2), −0.4·(−√2/2) + (−0.8)·(−√2/2)) = (0.2√2, 0.6√2).
    # Eq. 18: (0.4, −0.3) → ((−0.4 + 0.3)·√2/2, (0.4 + 0.3)·√2/2) = (−0.1·√2/2, 0.7·√2/2).
    # Rate: arm = (0, −0.5) → (0.1 − 0.5·(−0.5), 0.2 + 0, 0.5) = (0.35, 0.2, 0.5).
    "leader_in_quadrant_4_headings_across_pi": FormationCase(
        leader_pose=(0.4, -0.3, 3 * PI / 4),
        follower_pose=(0.0, 0.0, -3 * PI / 4),
        slot_distance_m=0.5,
        slot_angle_rad=3 * PI / 4,
        slot_in_leader_m=(-0.5 * HALF_SQRT2, 0.5 * HALF_SQRT2),
        slot_in_world_m=(0.4, -0.8),
        leader_in_follower_m=(-0.1 * HALF_SQRT2, 0.7 * HALF_SQRT2),
        slot_in_follower_m=(0.2 * math.sqrt(2.0), 0.6 * math.sqrt(2.0)),
        desired_heading_rad=3 * PI / 4,
        slot_rate=(0.35, 0.2, 0.5),
    ),
    # Leader due east, Δ = (0.5, 0): θ_mF = 0 and θ_mL = atan2(−0, −0.5) = −π, the wrap point.
    # Both face west; the leader's heading is given as −π, the follower's as π (the same heading):
    # θ_LF = wrap(0 − π) = π, θ_FL = wrap(−π − (−π)) = 0, φ = wrap(π − π + 0) = 0.
    # Eq. 17: slot 0.5 m at π/2 (the leader's left), (0, 0.5); the leader faces −x, so its left is
    # −y: R(π)·(0, 0.5) = (0, −0.5), world slot (0.5, −0.5).
    # Follower at the origin heading π: Δ = (0.5, −0.5) → (−0.5, 0.5).
    # Eq. 18: (0.5, 0) → (−0.5, 0).  Desired heading: the leader's, wrapped into (−π, π]: π.
    # Rate: arm = (0, −0.5) → (0.35, 0.2, 0.5).
    "bearing_on_the_wrap_at_pi": FormationCase(
        leader_pose=(0.5, 0.0, -PI),
        follower_pose=(0.0, 0.0, PI),
        slot_distance_m=0.5,
        slot_angle_rad=PI / 2,
        slot_in_leader_m=(0.0, 0.5),
        slot_in_world_m=(0.5, -0.5),
        leader_in_follower_m=(-0.5, 0.0),
        slot_in_follower_m=(-0.5, 0.5),
        desired_heading_rad=PI,
        slot_rate=(0.35, 0.2, 0.5),
    ),
    # A leader heading extrapolated past π, as the controller does with a peer's rate: 5π/4
    # is −3π/4 wrapped. Eq. 17: slot 0.5 m at −3π/4, (−0.35355, −0.35355); in the world it
    # points along 5π/4 − 3π/4 = π/2: offset (0, 0.5), world slot (1.0, 1.5).
    # Follower at (1.0, 0.5) heading 0: Δ = (0, 1.0) → (0, 1.0).
    # Eq. 18: the leader to the follower's left, θ_mF = π/2, (0, 0.5) → (0, 0.5).
    # Rate: arm = (0, 0.5) → (0.1 − 0.5·0.5, 0.2 + 0, 0.5) = (−0.15, 0.2, 0.5).
    "leader_heading_past_pi": FormationCase(
        leader_pose=(1.0, 1.0, 5 * PI / 4),
        follower_pose=(1.0, 0.5, 0.0),
        slot_distance_m=0.5,
        slot_angle_rad=-3 * PI / 4,
        slot_in_leader_m=(-0.5 * HALF_SQRT2, -0.5 * HALF_SQRT2),
        slot_in_world_m=(1.0, 1.5),
        leader_in_follower_m=(0.0, 0.5),
        slot_in_follower_m=(0.0, 1.0),
        desired_heading_rad=-3 * PI / 4,
        slot_rate=(-0.15, 0.2, 0.5),
    ),
}


def _pose(values: tuple[float, float, float]) -> np.ndarray:
    return np.array(values, dtype=np.float64)


@pytest.mark.parametrize("name", CASES)
def test_eq17_slot_in_leader_frame(name: str) -> None:
    case = CASES[name]
    x_dl, y_dl = slot_in_leader_frame(case.slot_distance_m, case.slot_angle_rad)
    np.testing.assert_allclose([x_dl, y_dl], case.slot_in_leader_m, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_slot_in_world_from_the_leader_pose(name: str) -> None:
    case = CASES[name]
    slot = follower_slot_in_world(
        _pose(case.leader_pose), case.slot_distance_m, case.slot_angle_rad
    )
    np.testing.assert_allclose(slot, case.slot_in_world_m, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_eq18_leader_seen_from_the_follower(name: str) -> None:
    # With a zero slot distance, eq. 19 leaves only eq. 18's (x_LF, y_LF).
    case = CASES[name]
    seen = follower_slot_in_follower_frame(
        _pose(case.leader_pose), _pose(case.follower_pose), 0.0, case.slot_angle_rad
    )
    np.testing.assert_allclose(seen, case.leader_in_follower_m, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_eqs17_to_21_slot_in_the_follower_frame(name: str) -> None:
    case = CASES[name]
    slot = follower_slot_in_follower_frame(
        _pose(case.leader_pose),
        _pose(case.follower_pose),
        case.slot_distance_m,
        case.slot_angle_rad,
    )
    np.testing.assert_allclose(slot, case.slot_in_follower_m, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_follower_frame_point_maps_back_to_the_world_slot(name: str) -> None:
    case = CASES[name]
    world = follower_frame_to_world(np.array(case.slot_in_follower_m), _pose(case.follower_pose))
    np.testing.assert_allclose(world, case.slot_in_world_m, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_desired_pose_is_the_slot_with_the_leaders_wrapped_heading(name: str) -> None:
    case = CASES[name]
    desired, rate = follower_reference(
        _pose(case.leader_pose),
        _pose(LEADER_RATE),
        _pose(case.follower_pose),
        case.slot_distance_m,
        case.slot_angle_rad,
    )
    np.testing.assert_allclose(desired[:2], case.slot_in_world_m, atol=1e-12)
    assert -PI < desired[2] <= PI
    assert desired[2] == pytest.approx(case.desired_heading_rad, abs=1e-12)
    np.testing.assert_allclose(rate, case.slot_rate, atol=1e-12)


def test_a_batch_of_cases_gives_the_same_rows_as_one_at_a_time() -> None:
    cases = list(CASES.values())
    leader = np.array([c.leader_pose for c in cases])
    follower = np.array([c.follower_pose for c in cases])
    distance = np.array([c.slot_distance_m for c in cases])
    angle = np.array([c.slot_angle_rad for c in cases])
    rates = np.tile(LEADER_RATE, (len(cases), 1))
    desired, rate = follower_reference(leader, rates, follower, distance, angle)
    np.testing.assert_allclose(
        follower_slot_in_follower_frame(leader, follower, distance, angle),
        [c.slot_in_follower_m for c in cases],
        atol=1e-12,
    )
    np.testing.assert_allclose(desired[:, :2], [c.slot_in_world_m for c in cases], atol=1e-12)
    np.testing.assert_allclose(desired[:, 2], [c.desired_heading_rad for c in cases], atol=1e-12)
    np.testing.assert_allclose(rate, [c.slot_rate for c in cases], atol=1e-12)


def _random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack(
        [rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n)]
    )


def test_eq19_matches_ground_truth_over_random_poses() -> None:
    rng = np.random.default_rng(3)
    n = 5000
    leader = _random_poses(rng, n)
    follower = _random_poses(rng, n)
    distance = rng.uniform(0.2, 3.0, n)
    angle = rng.uniform(-np.pi, np.pi, n)
    slot_in_follower = follower_slot_in_follower_frame(leader, follower, distance, angle)
    # Ground truth: place the slot in the world from the leader's pose, then express it in the
    # follower's frame by an independent rotation.
    truth_world = follower_slot_in_world(leader, distance, angle)
    rel = truth_world - follower[:, :2]
    c, s = np.cos(follower[:, 2]), np.sin(follower[:, 2])
    truth_in_follower = np.column_stack(
        [c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]]
    )
    np.testing.assert_allclose(slot_in_follower, truth_in_follower, atol=1e-9)
    np.testing.assert_allclose(
        follower_frame_to_world(slot_in_follower, follower), truth_world, atol=1e-9
    )


def test_follower_reference_velocity_is_slot_velocity() -> None:
    leader = np.array([1.0, 2.0, 0.4])
    rate = np.array([0.3, -0.2, 0.5])
    follower = np.array([0.0, 0.5, -1.0])
    dt = 1e-6
    pose0, rate0 = follower_reference(leader, rate, follower, 1.2, 2.5)
    pose1, _ = follower_reference(leader + rate * dt, rate, follower, 1.2, 2.5)
    np.testing.assert_allclose((pose1 - pose0) / dt, rate0, atol=1e-5)
    assert pose0[2] == pytest.approx(leader[2], abs=1e-12)

import numpy as np
import pytest

from robot_firmware.control.angles import wrap_angle_rad
from robot_firmware.control.formation import (
    follower_frame_to_world,
    follower_reference,
    follower_slot_in_follower_frame,
    follower_slot_in_world,
)


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


def test_eq21_phi_equals_heading_difference() -> None:
    rng = np.random.default_rng(4)
    leader = _random_poses(rng, 1000)
    follower = _random_poses(rng, 1000)
    dx, dy = leader[:, 0] - follower[:, 0], leader[:, 1] - follower[:, 1]
    theta_mf = np.arctan2(dy, dx)
    theta_ml = np.arctan2(-dy, -dx)
    theta_lf = theta_mf - follower[:, 2]
    theta_fl = theta_ml - leader[:, 2]
    phi = wrap_angle_rad(np.pi - theta_lf + theta_fl)
    np.testing.assert_allclose(
        np.cos(phi - (follower[:, 2] - leader[:, 2])), np.ones(1000), atol=1e-9
    )


def test_paper_eq20_arctangent_breaks_ground_truth() -> None:
    # Eq. 20 as printed, tan⁻¹(Δx/Δy), points the bearing the wrong way in most quadrants.
    rng = np.random.default_rng(5)
    leader = _random_poses(rng, 200)
    follower = _random_poses(rng, 200)
    dx, dy = leader[:, 0] - follower[:, 0], leader[:, 1] - follower[:, 1]
    printed = np.arctan(dx / dy)
    corrected = np.arctan2(dy, dx)
    assert np.mean(np.abs(wrap_angle_rad(printed - corrected)) > 1e-6) > 0.5


def test_follower_reference_velocity_is_slot_velocity() -> None:
    leader = np.array([1.0, 2.0, 0.4])
    rate = np.array([0.3, -0.2, 0.5])
    follower = np.array([0.0, 0.5, -1.0])
    dt = 1e-6
    pose0, rate0 = follower_reference(leader, rate, follower, 1.2, 2.5)
    pose1, _ = follower_reference(leader + rate * dt, rate, follower, 1.2, 2.5)
    np.testing.assert_allclose((pose1 - pose0) / dt, rate0, atol=1e-5)
    assert pose0[2] == pytest.approx(leader[2], abs=1e-12)

import numpy as np

from robot_firmware.control.estimation import EstimatorState, fuse_pose_fix, odometry_update
from robot_firmware.control.kinematics import wheel_speeds_from_pose_rate

RADIUS_M = 0.05
BASE_M = 0.25
CPR = 1_000_000  # fine counts so that quantisation does not hide the kinematics


def test_odometry_follows_a_driven_arc() -> None:
    state = fuse_pose_fix(
        EstimatorState.unlocalised(()), np.array([1.0, 2.0, 0.5]), np.array(True), 0.3
    )
    assert bool(state.localised)
    np.testing.assert_allclose(state.pose, [1.0, 2.0, 0.5])
    true_pose = np.array([1.0, 2.0, 0.5])
    wheel_angle = np.zeros(4)
    rate = np.array([0.2, 0.1, 0.4])
    dt = 0.01
    for _ in range(500):
        # The body moves at a constant world-frame rate; wheels turn accordingly.
        mid = true_pose[2] + 0.5 * rate[2] * dt
        wheel_angle += wheel_speeds_from_pose_rate(rate, np.array(mid), BASE_M) * dt / RADIUS_M
        true_pose = true_pose + rate * dt
        counts = np.floor(wheel_angle * CPR / (2 * np.pi)).astype(np.int64)
        state = odometry_update(state, counts, dt, CPR, RADIUS_M, BASE_M, 0.05)
    np.testing.assert_allclose(state.pose[:2], true_pose[:2], atol=1e-3)
    np.testing.assert_allclose(state.rate, rate, atol=1e-3)


def test_fix_is_blended_with_gain_and_ignored_when_invalid() -> None:
    state = EstimatorState(
        pose=np.array([0.0, 0.0, 3.0]),
        rate=np.zeros(3),
        previous_counts=np.zeros(4, dtype=np.int64),
        localised=np.array(True),
    )
    fused = fuse_pose_fix(state, np.array([1.0, -1.0, -3.0]), np.array(True), 0.25)
    np.testing.assert_allclose(fused.pose[:2], [0.25, -0.25])
    # The heading innovation wraps across ±π: +0.283 rad, not -6 rad.
    assert np.isclose(fused.pose[2], 3.0 + 0.25 * (2 * np.pi - 6.0))
    skipped = fuse_pose_fix(state, np.array([1.0, -1.0, -3.0]), np.array(False), 0.25)
    np.testing.assert_array_equal(skipped.pose, state.pose)

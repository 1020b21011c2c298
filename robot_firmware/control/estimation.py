"""Level 2 of the 5C architecture: the robot's own pose estimate.

Odometry integrates encoder count deltas through the inverse kinematics of eq. 11; a pose fix
from the indoor positioning receiver (DESIGN.md §4; the paper does not say how a global pose is
obtained) pulls the estimate toward it with a complementary-filter gain.  Without fixes the robot
dead-reckons and its error grows.  Before the first fix the estimate is not `localised`, and
the control step keeps the wheels still.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle_rad
from robot_firmware.control.kinematics import pose_rate_from_wheel_speeds

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class EstimatorState:
    """pose (..., 3), rate (..., 3) low-pass pose rate, last encoder counts (..., 4)."""

    pose: FloatArray
    rate: FloatArray
    previous_counts: IntArray
    localised: BoolArray

    @staticmethod
    def unlocalised(batch_shape: tuple[int, ...]) -> EstimatorState:
        return EstimatorState(
            pose=np.zeros(batch_shape + (3,)),
            rate=np.zeros(batch_shape + (3,)),
            previous_counts=np.zeros(batch_shape + (4,), dtype=np.int64),
            localised=np.zeros(batch_shape, dtype=bool),
        )


def odometry_update(
    state: EstimatorState,
    encoder_counts: IntArray,
    dt_s: float,
    counts_per_rev: int,
    wheel_radius_m: float,
    wheel_base_m: float,
    rate_filter_time_constant_s: float,
) -> EstimatorState:
    """Advance the estimate by the wheel travel measured since the previous tick (eq. 11)."""
    delta_counts = encoder_counts - state.previous_counts
    metres_per_count = 2.0 * np.pi * wheel_radius_m / counts_per_rev
    travel_m = delta_counts.astype(np.float64) * metres_per_count
    # Evaluate P# at the mid-step heading for second-order accuracy on turning robots.
    first = pose_rate_from_wheel_speeds(travel_m, state.pose[..., 2], wheel_base_m)
    mid_theta = state.pose[..., 2] + 0.5 * first[..., 2]
    step = pose_rate_from_wheel_speeds(travel_m, mid_theta, wheel_base_m)
    pose = state.pose + step
    pose[..., 2] = wrap_angle_rad(pose[..., 2])
    alpha = rate_filter_time_constant_s / (rate_filter_time_constant_s + dt_s)
    rate = alpha * state.rate + (1.0 - alpha) * (step / dt_s)
    return EstimatorState(
        pose=pose, rate=rate, previous_counts=encoder_counts, localised=state.localised
    )


def fuse_pose_fix(
    state: EstimatorState, fix_pose: FloatArray, fix_valid: BoolArray, fix_gain: float
) -> EstimatorState:
    """Blend a new pose fix into the estimate; the first fix after boot is taken whole."""
    gain = np.where(state.localised, fix_gain, 1.0)
    gain = np.where(fix_valid, gain, 0.0)[..., None]
    innovation = fix_pose - state.pose
    innovation[..., 2] = wrap_angle_rad(innovation[..., 2])
    pose = state.pose + gain * innovation
    pose[..., 2] = wrap_angle_rad(pose[..., 2])
    return EstimatorState(
        pose=pose,
        rate=state.rate,
        previous_counts=state.previous_counts,
        localised=state.localised | fix_valid,
    )

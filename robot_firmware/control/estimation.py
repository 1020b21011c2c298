"""Level 2 of the 5C architecture: the robot's own pose estimate.

Odometry integrates encoder count deltas through the inverse kinematics of eq. 11; a pose fix
from the indoor positioning receiver (DESIGN.md §4; the paper does not say how a global pose is
obtained) pulls the estimate toward it with a complementary-filter gain.  Without fixes the robot
dead-reckons and its error grows.  Before the first fix the estimate is not `localised`, and
the control step keeps the wheels still.

`odometry` and `fuse_fix` are the compiled forms (numba) the control step's kernel calls;
`odometry_update` and `fuse_pose_fix` are their array forms for any batch shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.angles import wrap_angle
from robot_firmware.control.kernels import njit
from robot_firmware.control.kinematics import body_rate
from robot_firmware.control.rows import as_rows, from_rows

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


@njit(cache=True)
def odometry(
    pose: FloatArray,
    rate: FloatArray,
    previous_counts: IntArray,
    counts: IntArray,
    dt_s: float,
    metres_per_count: float,
    wheel_base_m: float,
    rate_filter_time_constant_s: float,
    pose_out: FloatArray,
    rate_out: FloatArray,
) -> None:
    """One robot's pose advanced by the wheel travel since the previous tick (eq. 11), with P#
    evaluated at the mid-step heading for second-order accuracy on turning robots."""
    t1 = float(counts[0] - previous_counts[0]) * metres_per_count
    t2 = float(counts[1] - previous_counts[1]) * metres_per_count
    t3 = float(counts[2] - previous_counts[2]) * metres_per_count
    t4 = float(counts[3] - previous_counts[3]) * metres_per_count
    first = body_rate(t1, t2, t3, t4, pose[2], wheel_base_m)
    mid_theta = pose[2] + 0.5 * first[2]
    step = body_rate(t1, t2, t3, t4, mid_theta, wheel_base_m)
    alpha = rate_filter_time_constant_s / (rate_filter_time_constant_s + dt_s)
    for k in range(3):
        pose_out[k] = pose[k] + step[k]
        rate_out[k] = alpha * rate[k] + (1.0 - alpha) * (step[k] / dt_s)
    pose_out[2] = wrap_angle(pose_out[2])


@njit(cache=True)
def fuse_fix(
    pose: FloatArray, localised: bool, fix_pose: FloatArray, fix_valid: bool, fix_gain: float
) -> bool:
    """Blend a pose fix into `pose` in place (the first fix after boot is taken whole);
    returns the new `localised`."""
    gain = (fix_gain if localised else 1.0) if fix_valid else 0.0
    for k in range(3):
        innovation = fix_pose[k] - pose[k]
        if k == 2:
            innovation = wrap_angle(innovation)
        pose[k] = pose[k] + gain * innovation
    pose[2] = wrap_angle(pose[2])
    return localised or fix_valid


def metres_per_count(wheel_radius_m: float, counts_per_rev: int) -> float:
    """Wheel travel of one 4x-decoded encoder count."""
    return 2.0 * math.pi * wheel_radius_m / counts_per_rev


@njit(cache=True)
def _odometry_rows(
    pose: FloatArray,
    rate: FloatArray,
    previous_counts: IntArray,
    counts: IntArray,
    dt_s: float,
    metres_per_count: float,
    wheel_base_m: float,
    rate_filter_time_constant_s: float,
) -> tuple[FloatArray, FloatArray]:
    pose_out = np.empty((pose.shape[0], 3))
    rate_out = np.empty((pose.shape[0], 3))
    for i in range(pose.shape[0]):
        odometry(
            pose[i], rate[i], previous_counts[i], counts[i], dt_s, metres_per_count,
            wheel_base_m, rate_filter_time_constant_s, pose_out[i], rate_out[i],
        )  # fmt: skip
    return pose_out, rate_out


@njit(cache=True)
def _fuse_rows(
    pose: FloatArray, localised: BoolArray, fix_pose: FloatArray, fix_valid: BoolArray, gain: float
) -> tuple[FloatArray, BoolArray]:
    pose_out = pose.copy()
    localised_out = np.empty(pose.shape[0], dtype=np.bool_)
    for i in range(pose.shape[0]):
        localised_out[i] = fuse_fix(pose_out[i], localised[i], fix_pose[i], fix_valid[i], gain)
    return pose_out, localised_out


def odometry_update(
    state: EstimatorState,
    encoder_counts: ArrayLike,
    dt_s: float,
    counts_per_rev: int,
    wheel_radius_m: float,
    wheel_base_m: float,
    rate_filter_time_constant_s: float,
) -> EstimatorState:
    """Advance the estimate by the wheel travel measured since the previous tick (eq. 11)."""
    batch, (pose, rate, previous, counts) = as_rows(
        (state.pose, 1, np.float64),
        (state.rate, 1, np.float64),
        (state.previous_counts, 1, np.int64),
        (encoder_counts, 1, np.int64),
    )
    pose_out, rate_out = _odometry_rows(
        pose, rate, previous, counts, float(dt_s),
        metres_per_count(wheel_radius_m, counts_per_rev), float(wheel_base_m),
        float(rate_filter_time_constant_s),
    )  # fmt: skip
    return EstimatorState(
        pose=from_rows(pose_out, batch),
        rate=from_rows(rate_out, batch),
        previous_counts=from_rows(counts.copy(), batch),
        localised=np.broadcast_to(state.localised, batch).copy(),
    )


def fuse_pose_fix(
    state: EstimatorState, fix_pose: ArrayLike, fix_valid: ArrayLike, fix_gain: float
) -> EstimatorState:
    """Blend a new pose fix into the estimate; the first fix after boot is taken whole."""
    batch, (pose, localised, fix, valid) = as_rows(
        (state.pose, 1, np.float64),
        (state.localised, 0, np.bool_),
        (fix_pose, 1, np.float64),
        (fix_valid, 0, np.bool_),
    )
    pose_out, localised_out = _fuse_rows(pose, localised, fix, valid, float(fix_gain))
    return EstimatorState(
        pose=from_rows(pose_out, batch),
        rate=state.rate,
        previous_counts=state.previous_counts,
        localised=from_rows(localised_out, batch),
    )

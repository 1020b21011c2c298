"""Leader-follower formation geometry, eqs. 17-21, with the corrections of DESIGN.md §6.

Eq. 17: the follower's slot in the leader's frame, (x_DL, y_DL) = L_DL·(cos θ_DL, sin θ_DL).
Eq. 18: the leader seen from the follower, (x_LF, y_LF) = L_LF·(cos θ_LF, sin θ_LF).
Eq. 19: the slot in the follower's frame, rotating (x_DL, y_DL) by -φ and adding (x_LF, y_LF).
Eq. 20 (corrected with atan2, arguments in (y, x) order): θ_mF = atan2(y_LO - y_FO, x_LO - x_FO),
        θ_mL = atan2(y_FO - y_LO, x_FO - x_LO), θ_LF = θ_mF - θ_FO, θ_FL = θ_mL - θ_LO.
Eq. 21: φ = π - θ_LF + θ_FL (which equals θ_FO - θ_LO modulo 2π).
All angles are wrapped to (-π, π].

`follower_slot_in_follower_frame` is the chain the firmware runs from relative measurements;
`follower_slot_in_world` is the same point written directly in world coordinates, used by the
metrics (from the leader's true pose) and by tests as ground truth.

`slot_in_follower_frame`, `follower_to_world`, `slot_in_world` and `slot_reference` are the
compiled scalar forms (numba) that the control step's kernel calls; the functions named
`follower_*` after them are their array forms for any batch shape.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.angles import wrap_angle
from robot_firmware.control.kernels import njit
from robot_firmware.control.rows import as_rows, from_rows

FloatArray = NDArray[np.float64]


@njit(cache=True)
def slot_in_follower_frame(
    leader_x: float,
    leader_y: float,
    leader_theta: float,
    follower_x: float,
    follower_y: float,
    follower_theta: float,
    distance_m: float,
    angle_rad: float,
) -> tuple[float, float]:
    """Eqs. 17-21: the follower's desired position expressed in its own frame."""
    x_dl = distance_m * math.cos(angle_rad)  # eq. 17
    y_dl = distance_m * math.sin(angle_rad)
    dx = leader_x - follower_x
    dy = leader_y - follower_y
    theta_mf = math.atan2(dy, dx)  # eq. 20, corrected
    theta_ml = math.atan2(-dy, -dx)
    theta_lf = wrap_angle(theta_mf - follower_theta)
    theta_fl = wrap_angle(theta_ml - leader_theta)
    phi = wrap_angle(math.pi - theta_lf + theta_fl)  # eq. 21
    l_lf = math.hypot(dx, dy)
    x_lf = l_lf * math.cos(theta_lf)  # eq. 18
    y_lf = l_lf * math.sin(theta_lf)
    cp = math.cos(phi)
    sp = math.sin(phi)
    return x_dl * cp + y_dl * sp + x_lf, -x_dl * sp + y_dl * cp + y_lf  # eq. 19


@njit(cache=True)
def follower_to_world(
    x_f: float, y_f: float, follower_x: float, follower_y: float, follower_theta: float
) -> tuple[float, float]:
    """Rotate and translate a point from the follower's frame to world coordinates."""
    c = math.cos(follower_theta)
    s = math.sin(follower_theta)
    return follower_x + c * x_f - s * y_f, follower_y + s * x_f + c * y_f


@njit(cache=True)
def slot_in_world(
    leader_x: float, leader_y: float, leader_theta: float, distance_m: float, angle_rad: float
) -> tuple[float, float]:
    """The slot of eq. 17 placed in world coordinates from the leader's pose."""
    x_dl = distance_m * math.cos(angle_rad)
    y_dl = distance_m * math.sin(angle_rad)
    c = math.cos(leader_theta)
    s = math.sin(leader_theta)
    return leader_x + c * x_dl - s * y_dl, leader_y + s * x_dl + c * y_dl


@njit(cache=True)
def slot_reference(
    leader_pose: FloatArray,
    leader_rate: FloatArray,
    follower_pose: FloatArray,
    distance_m: float,
    angle_rad: float,
    desired_out: FloatArray,
    rate_out: FloatArray,
) -> None:
    """Desired pose and pose rate (3,) of one follower in world coordinates.

    The position comes from eqs. 17-21 in the follower's frame, mapped back to the world; the
    heading is the leader's, wrapped to (-π, π] (a peer's heading extrapolated by its rate can
    pass ±π).  The rate is the slot's velocity when the leader moves with
    `leader_rate`: ṗ_L + θ̇_L × R(θ_L)·(x_DL, y_DL).
    """
    x_f, y_f = slot_in_follower_frame(
        leader_pose[0], leader_pose[1], leader_pose[2],
        follower_pose[0], follower_pose[1], follower_pose[2], distance_m, angle_rad,
    )  # fmt: skip
    x_w, y_w = follower_to_world(x_f, y_f, follower_pose[0], follower_pose[1], follower_pose[2])
    desired_out[0] = x_w
    desired_out[1] = y_w
    desired_out[2] = wrap_angle(leader_pose[2])
    arm_x = x_w - leader_pose[0]
    arm_y = y_w - leader_pose[1]
    spin = leader_rate[2]
    rate_out[0] = leader_rate[0] - spin * arm_y
    rate_out[1] = leader_rate[1] + spin * arm_x
    rate_out[2] = spin


@njit(cache=True)
def _slot_follower_rows(
    leader: FloatArray, follower: FloatArray, distance: FloatArray, angle: FloatArray
) -> FloatArray:
    out = np.empty((leader.shape[0], 2))
    for i in range(leader.shape[0]):
        out[i, 0], out[i, 1] = slot_in_follower_frame(
            leader[i, 0], leader[i, 1], leader[i, 2],
            follower[i, 0], follower[i, 1], follower[i, 2], distance[i], angle[i],
        )  # fmt: skip
    return out


@njit(cache=True)
def _to_world_rows(point: FloatArray, follower: FloatArray) -> FloatArray:
    out = np.empty((point.shape[0], 2))
    for i in range(point.shape[0]):
        out[i, 0], out[i, 1] = follower_to_world(
            point[i, 0], point[i, 1], follower[i, 0], follower[i, 1], follower[i, 2]
        )
    return out


@njit(cache=True)
def _slot_world_rows(leader: FloatArray, distance: FloatArray, angle: FloatArray) -> FloatArray:
    out = np.empty((leader.shape[0], 2))
    for i in range(leader.shape[0]):
        out[i, 0], out[i, 1] = slot_in_world(
            leader[i, 0], leader[i, 1], leader[i, 2], distance[i], angle[i]
        )
    return out


@njit(cache=True)
def _reference_rows(
    leader: FloatArray, rate: FloatArray, follower: FloatArray, distance: FloatArray,
    angle: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    desired = np.empty((leader.shape[0], 3))
    desired_rate = np.empty((leader.shape[0], 3))
    for i in range(leader.shape[0]):
        slot_reference(
            leader[i], rate[i], follower[i], distance[i], angle[i], desired[i], desired_rate[i]
        )
    return desired, desired_rate


def slot_in_leader_frame(
    distance_m: ArrayLike, angle_rad: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Eq. 17, as arrays: (x_DL, y_DL) = L_DL·(cos θ_DL, sin θ_DL)."""
    slot = follower_slot_in_world(np.zeros(3), distance_m, angle_rad)
    return slot[..., 0], slot[..., 1]


def follower_slot_in_follower_frame(
    leader_pose: ArrayLike,
    follower_pose: ArrayLike,
    distance_m: ArrayLike,
    angle_rad: ArrayLike,
) -> FloatArray:
    """Eqs. 17-21: the follower's desired position expressed in its own frame, shape (..., 2)."""
    batch, rows = as_rows(
        (leader_pose, 1, np.float64),
        (follower_pose, 1, np.float64),
        (distance_m, 0, np.float64),
        (angle_rad, 0, np.float64),
    )
    return from_rows(_slot_follower_rows(*rows), batch)


def follower_frame_to_world(point_in_follower: ArrayLike, follower_pose: ArrayLike) -> FloatArray:
    """Rotate and translate a point from the follower's frame to world coordinates."""
    batch, rows = as_rows((point_in_follower, 1, np.float64), (follower_pose, 1, np.float64))
    return from_rows(_to_world_rows(*rows), batch)


def follower_slot_in_world(
    leader_pose: ArrayLike, distance_m: ArrayLike, angle_rad: ArrayLike
) -> FloatArray:
    """The slot of eq. 17 placed in world coordinates from the leader's pose, shape (..., 2)."""
    batch, rows = as_rows(
        (leader_pose, 1, np.float64), (distance_m, 0, np.float64), (angle_rad, 0, np.float64)
    )
    return from_rows(_slot_world_rows(*rows), batch)


def follower_reference(
    leader_pose: ArrayLike,
    leader_rate: ArrayLike,
    follower_pose: ArrayLike,
    distance_m: ArrayLike,
    angle_rad: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Desired pose (..., 3) and pose rate (..., 3) of a follower (`slot_reference`)."""
    batch, rows = as_rows(
        (leader_pose, 1, np.float64),
        (leader_rate, 1, np.float64),
        (follower_pose, 1, np.float64),
        (distance_m, 0, np.float64),
        (angle_rad, 0, np.float64),
    )
    desired, rate = _reference_rows(*rows)
    return from_rows(desired, batch), from_rows(rate, batch)

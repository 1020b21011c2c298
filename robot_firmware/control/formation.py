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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle_rad

FloatArray = NDArray[np.float64]


def slot_in_leader_frame(
    distance_m: FloatArray | float, angle_rad: FloatArray | float
) -> tuple[FloatArray, FloatArray]:
    """Eq. 17."""
    d = np.asarray(distance_m, dtype=np.float64)
    a = np.asarray(angle_rad, dtype=np.float64)
    return d * np.cos(a), d * np.sin(a)


def follower_slot_in_follower_frame(
    leader_pose: FloatArray,
    follower_pose: FloatArray,
    distance_m: FloatArray | float,
    angle_rad: FloatArray | float,
) -> FloatArray:
    """Eqs. 17-21: the follower's desired position expressed in its own frame, shape (..., 2)."""
    x_dl, y_dl = slot_in_leader_frame(distance_m, angle_rad)  # eq. 17
    dx = leader_pose[..., 0] - follower_pose[..., 0]
    dy = leader_pose[..., 1] - follower_pose[..., 1]
    theta_fo = follower_pose[..., 2]
    theta_lo = leader_pose[..., 2]
    theta_mf = np.arctan2(dy, dx)  # eq. 20, corrected
    theta_ml = np.arctan2(-dy, -dx)
    theta_lf = wrap_angle_rad(theta_mf - theta_fo)
    theta_fl = wrap_angle_rad(theta_ml - theta_lo)
    phi = wrap_angle_rad(np.pi - theta_lf + theta_fl)  # eq. 21
    l_lf = np.hypot(dx, dy)
    x_lf = l_lf * np.cos(theta_lf)  # eq. 18
    y_lf = l_lf * np.sin(theta_lf)
    cp = np.cos(phi)
    sp = np.sin(phi)
    x_df = x_dl * cp + y_dl * sp + x_lf  # eq. 19
    y_df = -x_dl * sp + y_dl * cp + y_lf
    return np.stack((x_df, y_df), axis=-1)


def follower_frame_to_world(point_in_follower: FloatArray, follower_pose: FloatArray) -> FloatArray:
    """Rotate and translate a point from the follower's frame to world coordinates."""
    c = np.cos(follower_pose[..., 2])
    s = np.sin(follower_pose[..., 2])
    x = follower_pose[..., 0] + c * point_in_follower[..., 0] - s * point_in_follower[..., 1]
    y = follower_pose[..., 1] + s * point_in_follower[..., 0] + c * point_in_follower[..., 1]
    return np.stack((x, y), axis=-1)


def follower_slot_in_world(
    leader_pose: FloatArray, distance_m: FloatArray | float, angle_rad: FloatArray | float
) -> FloatArray:
    """The slot of eq. 17 placed in world coordinates from the leader's pose, shape (..., 2)."""
    x_dl, y_dl = slot_in_leader_frame(distance_m, angle_rad)
    c = np.cos(leader_pose[..., 2])
    s = np.sin(leader_pose[..., 2])
    return np.stack(
        (leader_pose[..., 0] + c * x_dl - s * y_dl, leader_pose[..., 1] + s * x_dl + c * y_dl),
        axis=-1,
    )


def follower_reference(
    leader_pose: FloatArray,
    leader_rate: FloatArray,
    follower_pose: FloatArray,
    distance_m: FloatArray | float,
    angle_rad: FloatArray | float,
) -> tuple[FloatArray, FloatArray]:
    """Desired pose (..., 3) and pose rate (..., 3) of a follower in world coordinates.

    The position comes from eqs. 17-21 in the follower's frame, mapped back to the world; the
    heading is the leader's, wrapped to (-π, π] (a peer's heading extrapolated by its rate can
    pass ±π).  The rate is the slot's velocity when the leader moves with
    `leader_rate`: ṗ_L + θ̇_L × R(θ_L)·(x_DL, y_DL).
    """
    slot_f = follower_slot_in_follower_frame(leader_pose, follower_pose, distance_m, angle_rad)
    slot_w = follower_frame_to_world(slot_f, follower_pose)
    desired = np.concatenate((slot_w, wrap_angle_rad(leader_pose[..., 2:3])), axis=-1)
    arm_x = slot_w[..., 0] - leader_pose[..., 0]
    arm_y = slot_w[..., 1] - leader_pose[..., 1]
    spin = leader_rate[..., 2]
    rate = np.stack(
        (leader_rate[..., 0] - spin * arm_y, leader_rate[..., 1] + spin * arm_x, spin), axis=-1
    )
    return desired, rate

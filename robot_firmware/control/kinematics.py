"""Kinematics of the four-wheel Swedish-wheel robot, eqs. 9-11.

Eq. 9 maps the world-frame pose rate [ẋ, ẏ, θ̇] to the wheels' rim speeds v_i = r·ω_i through
the 4x3 matrix P(θ) with δ = π/4.  Eq. 10 of the paper prints a wrong inverse; the left
pseudo-inverse used here is the one in DESIGN.md §6: PᵀP = diag(2, 2, 4L²), so

    P# = (PᵀP)⁻¹Pᵀ = [[-s/2, -c/2,  s/2,  c/2],
                      [ c/2, -s/2, -c/2,  s/2],
                      [1/4L, 1/4L, 1/4L, 1/4L]],   s = sin(θ+π/4), c = cos(θ+π/4),

and P#·P = I for every θ.  Eq. 11 (inverse kinematics) is [ẋ, ẏ, θ̇] = P#(θ)·v.

The matrix forms are for tests and readers; the control loop and the physics use the
element-wise forms below, which cost a handful of array operations for any batch shape.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

WHEEL_ANGLE_OFFSET_RAD = np.pi / 4.0
"""The paper's δ in eq. 9: the wheels sit at 45° to the body axes."""

FloatArray = NDArray[np.float64]


def kinematics_matrix(theta_rad: ArrayLike, wheel_base_m: float) -> FloatArray:
    """P(θ) of eq. 9, shape (..., 4, 3): wheel rim speeds = P(θ) @ [ẋ, ẏ, θ̇]."""
    theta = np.asarray(theta_rad, dtype=np.float64)
    s = np.sin(theta + WHEEL_ANGLE_OFFSET_RAD)
    c = np.cos(theta + WHEEL_ANGLE_OFFSET_RAD)
    L = np.full_like(theta, wheel_base_m)
    rows = [(-s, c, L), (-c, -s, L), (s, -c, L), (c, s, L)]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def pseudo_inverse(theta_rad: ArrayLike, wheel_base_m: float) -> FloatArray:
    """P#(θ), the corrected left pseudo-inverse of eq. 10, shape (..., 3, 4)."""
    theta = np.asarray(theta_rad, dtype=np.float64)
    s = np.sin(theta + WHEEL_ANGLE_OFFSET_RAD)
    c = np.cos(theta + WHEEL_ANGLE_OFFSET_RAD)
    q = np.full_like(theta, 1.0 / (4.0 * wheel_base_m))
    rows = [(-s / 2, -c / 2, s / 2, c / 2), (c / 2, -s / 2, -c / 2, s / 2), (q, q, q, q)]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def wheel_speeds_from_pose_rate(
    pose_rate: FloatArray, theta_rad: FloatArray, wheel_base_m: float
) -> FloatArray:
    """Eq. 9 element-wise: pose_rate (..., 3) [m/s, m/s, rad/s] -> wheel rim speeds (..., 4) m/s."""
    phi = theta_rad + WHEEL_ANGLE_OFFSET_RAD
    s = np.sin(phi)
    c = np.cos(phi)
    xd = pose_rate[..., 0]
    yd = pose_rate[..., 1]
    spin = wheel_base_m * pose_rate[..., 2]
    a = -s * xd + c * yd
    b = -c * xd - s * yd
    return np.stack((a + spin, b + spin, spin - a, spin - b), axis=-1)


def pose_rate_from_wheel_speeds(
    wheel_speed_mps: FloatArray, theta_rad: FloatArray, wheel_base_m: float
) -> FloatArray:
    """Eq. 11 element-wise: wheel rim speeds (..., 4) m/s -> pose rate (..., 3)."""
    phi = theta_rad + WHEEL_ANGLE_OFFSET_RAD
    s = np.sin(phi)
    c = np.cos(phi)
    v1 = wheel_speed_mps[..., 0]
    v2 = wheel_speed_mps[..., 1]
    v3 = wheel_speed_mps[..., 2]
    v4 = wheel_speed_mps[..., 3]
    half_a = 0.5 * (v3 - v1)
    half_b = 0.5 * (v4 - v2)
    xd = s * half_a + c * half_b
    yd = -c * half_a + s * half_b
    thd = (v1 + v2 + v3 + v4) / (4.0 * wheel_base_m)
    return np.stack((xd, yd, thd), axis=-1)

"""Kinematics of the four-wheel Swedish-wheel robot, eqs. 9-11.

Eq. 9 maps the world-frame pose rate [ẋ, ẏ, θ̇] to the wheels' rim speeds v_i = r·ω_i through
the 4x3 matrix P(θ) with δ = π/4.  Eq. 10 of the paper prints a wrong inverse; the left
pseudo-inverse used here is the one in DESIGN.md §6: PᵀP = diag(2, 2, 4L²), so

    P# = (PᵀP)⁻¹Pᵀ = [[-s/2, -c/2,  s/2,  c/2],
                      [ c/2, -s/2, -c/2,  s/2],
                      [1/4L, 1/4L, 1/4L, 1/4L]],   s = sin(θ+π/4), c = cos(θ+π/4),

and P#·P = I for every θ.  Eq. 11 (inverse kinematics) is [ẋ, ẏ, θ̇] = P#(θ)·v.

The matrix forms are for tests and readers.  The control loop and the physics use the
element-wise forms: `rim_speeds` and `body_rate`, compiled scalar functions that the kernels of
the control step and of the body step call, and their array forms for any batch shape.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.kernels import njit
from robot_firmware.control.rows import as_rows, from_rows

WHEEL_ANGLE_OFFSET_RAD = math.pi / 4.0
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


@njit(cache=True)
def rim_speeds(
    xdot: float, ydot: float, thetadot: float, theta_rad: float, wheel_base_m: float
) -> tuple[float, float, float, float]:
    """Eq. 9 element-wise: a pose rate [m/s, m/s, rad/s] -> the four wheel rim speeds (m/s)."""
    phi = theta_rad + WHEEL_ANGLE_OFFSET_RAD
    s = math.sin(phi)
    c = math.cos(phi)
    spin = wheel_base_m * thetadot
    a = -s * xdot + c * ydot
    b = -c * xdot - s * ydot
    return a + spin, b + spin, spin - a, spin - b


@njit(cache=True)
def body_rate(
    v1: float, v2: float, v3: float, v4: float, theta_rad: float, wheel_base_m: float
) -> tuple[float, float, float]:
    """Eq. 11 element-wise: wheel rim speeds (m/s) -> the pose rate [ẋ, ẏ, θ̇]."""
    phi = theta_rad + WHEEL_ANGLE_OFFSET_RAD
    s = math.sin(phi)
    c = math.cos(phi)
    half_a = 0.5 * (v3 - v1)
    half_b = 0.5 * (v4 - v2)
    return (
        s * half_a + c * half_b,
        -c * half_a + s * half_b,
        (v1 + v2 + v3 + v4) / (4.0 * wheel_base_m),
    )


@njit(cache=True)
def _rim_speed_rows(rate: FloatArray, theta: FloatArray, wheel_base_m: float) -> FloatArray:
    out = np.empty((rate.shape[0], 4))
    for i in range(rate.shape[0]):
        v = rim_speeds(rate[i, 0], rate[i, 1], rate[i, 2], theta[i], wheel_base_m)
        for k in range(4):
            out[i, k] = v[k]
    return out


@njit(cache=True)
def _body_rate_rows(speed: FloatArray, theta: FloatArray, wheel_base_m: float) -> FloatArray:
    out = np.empty((speed.shape[0], 3))
    for i in range(speed.shape[0]):
        r = body_rate(speed[i, 0], speed[i, 1], speed[i, 2], speed[i, 3], theta[i], wheel_base_m)
        for k in range(3):
            out[i, k] = r[k]
    return out


def wheel_speeds_from_pose_rate(
    pose_rate: ArrayLike, theta_rad: ArrayLike, wheel_base_m: float
) -> FloatArray:
    """Eq. 9: pose_rate (..., 3) [m/s, m/s, rad/s] -> wheel rim speeds (..., 4) m/s."""
    batch, (rate, theta) = as_rows((pose_rate, 1, np.float64), (theta_rad, 0, np.float64))
    return from_rows(_rim_speed_rows(rate, theta, float(wheel_base_m)), batch)


def pose_rate_from_wheel_speeds(
    wheel_speed_mps: ArrayLike, theta_rad: ArrayLike, wheel_base_m: float
) -> FloatArray:
    """Eq. 11: wheel rim speeds (..., 4) m/s -> pose rate (..., 3)."""
    batch, (speed, theta) = as_rows((wheel_speed_mps, 1, np.float64), (theta_rad, 0, np.float64))
    return from_rows(_body_rate_rows(speed, theta, float(wheel_base_m)), batch)

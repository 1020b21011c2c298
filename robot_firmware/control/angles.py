"""Angle wrapping used by every module that compares orientations (DESIGN.md §6, eq. 20).

`wrap_angle` is the compiled scalar form the control and physics kernels call;
`wrap_angle_rad` is the same function as a numpy ufunc for arrays.
"""

from __future__ import annotations

import math

from robot_firmware.control.kernels import njit, vectorize

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to (-π, π] (π - ((π - a) mod 2π), the floored modulo)."""
    return math.pi - (math.pi - angle_rad) % TWO_PI


@vectorize(["float64(float64)"], cache=True)
def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap angles to (-π, π], element-wise over any array."""
    return wrap_angle(angle_rad)

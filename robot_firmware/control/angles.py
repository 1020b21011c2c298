"""Angle wrapping used by every module that compares orientations (DESIGN.md §6, eq. 20)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def wrap_angle_rad(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles to (-π, π]."""
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return np.asarray(wrapped, dtype=np.float64)

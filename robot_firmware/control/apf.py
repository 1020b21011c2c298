"""Artificial potential field repulsion, eqs. 22-25, with the corrections of DESIGN.md §6.

For each source j (another robot, or an obstacle point seen by sonar) within the influence
distance ρ₀ of robot i:

    U_ij = ½ ς (1/ρ_ij - 1/ρ₀)²                                   (eq. 23, one pair)
    F_ij = -∇U_ij = ς (1/ρ_ij - 1/ρ₀) (1/ρ_ij²) n_ij                 (eq. 25, one pair)

where ρ_ij is the gap between the two bodies (not the centre distance) and n_ij is the unit
vector from the source's centre to robot i's centre.  The sums of eqs. 23 and 25 run over j ≠ i
and the ρ ≤ ρ₀ test is applied per pair.  Near contact 1/ρ³ diverges, so ρ is floored at
`min_gap_m` and the total force is clipped to `max_force`; inside that floor the force no
longer equals the gradient.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def repulsive_potential(
    gap_m: FloatArray, valid: BoolArray, gain: float, influence_m: float
) -> FloatArray:
    """Eq. 23 summed over the last axis of `gap_m` (sources)."""
    rho = np.maximum(gap_m, 1e-12)
    term = 0.5 * gain * (1.0 / rho - 1.0 / influence_m) ** 2
    active = valid & (gap_m <= influence_m)
    return np.asarray(np.sum(np.where(active, term, 0.0), axis=-1), dtype=np.float64)


def repulsive_force(
    direction_from_source: FloatArray,
    gap_m: FloatArray,
    valid: BoolArray,
    gain: float,
    influence_m: float,
    min_gap_m: float,
) -> FloatArray:
    """Eq. 25 summed over sources.

    direction_from_source: (..., K, 2) unit vectors from each source's centre to the robot.
    gap_m: (..., K) body-to-body gaps.  valid: (..., K) which sources exist.
    Returns the force (..., 2) before clipping.
    """
    rho = np.maximum(gap_m, min_gap_m)
    magnitude = gain * (1.0 / rho - 1.0 / influence_m) / (rho * rho)
    magnitude = np.where(valid & (gap_m <= influence_m), magnitude, 0.0)
    return np.asarray(np.sum(magnitude[..., None] * direction_from_source, axis=-2))


def clip_norm(vector: FloatArray, max_norm: float) -> FloatArray:
    """Scale vectors (..., 2) down to at most `max_norm`, keeping their direction."""
    norm = np.hypot(vector[..., 0], vector[..., 1])
    scale = np.minimum(1.0, max_norm / np.maximum(norm, 1e-12))
    return vector * scale[..., None]

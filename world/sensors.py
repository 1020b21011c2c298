"""Sensor synthesis: the sonar ring and the indoor positioning fix (DESIGN.md §4).

Sonar: each transducer sits on the body's rim and looks along its beam axis with a cone of
`beam_half_width_rad`.  It reports the gap to the nearest surface of any circle (obstacle or
other robot body) inside the cone: a circle whose centre lies within the cone is met at its
nearest point, one that only grazes the cone is met along the cone's edge ray.  Readings get
Gaussian noise and are limited to [min, max] range; beyond max range there is no echo (inf).

Positioning fix: the true pose plus Gaussian noise, as a lab's motion-capture or UWB system
delivers it; the world decides when one is due and whether it is valid.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from swarm_config.sensors import PositioningParams, SonarParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def sonar_gaps(
    pose: FloatArray,
    beam_angles_rad: FloatArray,
    target_centres_m: FloatArray,
    target_radii_m: FloatArray,
    target_valid: BoolArray,
    body_radius_m: float,
    noise: FloatArray,
    params: SonarParams,
) -> FloatArray:
    """Gap readings (..., S) of a ring of S transducers.

    pose (..., 3); beam_angles_rad (S,) in the body frame; targets (..., T, 2), (..., T) and a
    validity mask (..., T) (e.g. excluding the robot itself); noise: standard normal (..., S).
    """
    to_target = target_centres_m - pose[..., None, :2]  # (..., T, 2)
    beam = pose[..., 2:3] + beam_angles_rad  # (..., S)
    ux = np.cos(beam)[..., :, None]
    uy = np.sin(beam)[..., :, None]
    tx = to_target[..., None, :, 0]
    ty = to_target[..., None, :, 1]
    along = tx * ux + ty * uy  # (..., S, T): d·cos(off-axis angle)
    across = np.abs(ux * ty - uy * tx)  # d·sin(off-axis angle)
    # Rotate the target's direction onto the cone's nearer edge: d·sin(off - hw) is how far the
    # centre lies from the edge ray (negative: inside the cone), d·cos(off - hw) how far along.
    cos_hw = np.cos(params.beam_half_width_rad)
    sin_hw = np.sin(params.beam_half_width_rad)
    edge_miss = across * cos_hw - along * sin_hw
    inside = edge_miss <= 0.0
    dist = np.sqrt(tx * tx + ty * ty)
    edge_along = np.where(inside, dist, along * cos_hw + across * sin_hw)
    edge_miss = np.where(inside, 0.0, edge_miss)
    radius = target_radii_m[..., None, :]
    hit = (edge_miss < radius) & (edge_along > 0.0) & target_valid[..., None, :]
    chord = np.sqrt(np.maximum(radius * radius - edge_miss * edge_miss, 0.0))
    gap = np.where(hit, edge_along - chord - body_radius_m, np.inf)
    nearest = np.min(gap, axis=-1)
    reading = nearest + params.noise_std_m * noise
    reading = np.maximum(reading, params.min_range_m)
    return np.where(reading <= params.max_range_m, reading, np.inf)


def pose_fix(pose: FloatArray, noise: FloatArray, params: PositioningParams) -> FloatArray:
    """A positioning fix (..., 3) from the true pose and standard normal draws (..., 3)."""
    scale = np.array(
        [params.position_noise_std_m, params.position_noise_std_m, params.heading_noise_std_rad]
    )
    return pose + scale * noise

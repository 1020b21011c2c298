"""Sensor synthesis: the sonar ring and the indoor positioning fix (DESIGN.md §4).

Sonar: each transducer sits on the body's rim and looks along its beam axis with a cone of
`beam_half_width_rad`.  It reports the gap to the nearest surface of any circle (obstacle or
other robot body) inside the cone: a circle whose centre lies within the cone is met at its
nearest point, one that only grazes the cone is met along the cone's edge ray.  Readings get
Gaussian noise and are limited to [min, max] range; beyond max range there is no echo (inf).

Positioning fix: the true pose plus Gaussian noise, as a lab's motion-capture or UWB system
delivers it; the world decides when one is due and whether it is valid.

The math is compiled (numba): `sonar_reading` is one transducer's reading and `fix_axis` one
axis of a fix; the array forms `sonar_gaps` and `pose_fix` run them over any batch shape (the
world process), and the batch simulator's compiled tick loop calls them directly
(services/sim/ticks.py).  tests/world/oracle.py states the same sensors in numpy.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, vectorize
from numpy.typing import NDArray

from robot_firmware.control.rows import as_rows, from_rows
from swarm_config.sensors import PositioningParams, SonarParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
SonarConstants = tuple[float, float, float, float, float, float]
"""cos and sin of the beam half-width, noise std, min and max range, body radius."""


def sonar_constants(params: SonarParams, body_radius_m: float) -> SonarConstants:
    """`params` as `sonar_reading` takes them."""
    return (
        math.cos(params.beam_half_width_rad),
        math.sin(params.beam_half_width_rad),
        float(params.noise_std_m),
        float(params.min_range_m),
        float(params.max_range_m),
        float(body_radius_m),
    )


@njit(cache=True)
def sonar_reading(
    x_m: float,
    y_m: float,
    beam_rad: float,
    target_centres_m: FloatArray,
    target_radii_m: FloatArray,
    target_valid: BoolArray,
    noise: float,
    sonar: SonarConstants,
) -> float:
    """One transducer looking along world angle `beam_rad` from a body centred at (x, y).

    Targets (T, 2), (T,) and a validity mask (T,); noise is one standard normal draw.
    """
    cos_hw, sin_hw, noise_std_m, min_range_m, max_range_m, body_radius_m = sonar
    ux = math.cos(beam_rad)
    uy = math.sin(beam_rad)
    nearest = math.inf
    for t in range(target_radii_m.shape[0]):
        tx = target_centres_m[t, 0] - x_m
        ty = target_centres_m[t, 1] - y_m
        along = tx * ux + ty * uy  # d·cos(off-axis angle)
        across = abs(ux * ty - uy * tx)  # d·sin(off-axis angle)
        # Rotate the target's direction onto the cone's nearer edge: d·sin(off - hw) is how far
        # the centre lies from the edge ray (negative: inside the cone), d·cos(off - hw) how far
        # along it.
        edge_miss = across * cos_hw - along * sin_hw
        if edge_miss <= 0.0:
            edge_along = math.sqrt(tx * tx + ty * ty)
            edge_miss = 0.0
        else:
            edge_along = along * cos_hw + across * sin_hw
        radius = target_radii_m[t]
        if edge_miss < radius and edge_along > 0.0 and target_valid[t]:
            chord = math.sqrt(max(radius * radius - edge_miss * edge_miss, 0.0))
            nearest = min(nearest, edge_along - chord - body_radius_m)
    reading = max(nearest + noise_std_m * noise, min_range_m)
    return reading if reading <= max_range_m else math.inf


@njit(cache=True)
def _sonar_rows(
    pose: FloatArray,
    beams: FloatArray,
    centres: FloatArray,
    radii: FloatArray,
    valid: BoolArray,
    noise: FloatArray,
    sonar: SonarConstants,
) -> FloatArray:
    out = np.empty((pose.shape[0], beams.shape[0]))
    for i in range(pose.shape[0]):
        for s in range(beams.shape[0]):
            out[i, s] = sonar_reading(
                pose[i, 0], pose[i, 1], pose[i, 2] + beams[s], centres[i], radii[i], valid[i],
                noise[i, s], sonar,
            )  # fmt: skip
    return out


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
    beams = np.asarray(beam_angles_rad, dtype=np.float64).reshape(-1)
    batch, (p, centres, radii, valid, draws) = as_rows(
        (pose, 1, np.float64),
        (target_centres_m, 2, np.float64),
        (target_radii_m, 1, np.float64),
        (target_valid, 1, np.bool_),
        (noise, 1, np.float64),
    )
    readings = _sonar_rows(
        p, beams, centres, radii, valid, draws, sonar_constants(params, body_radius_m)
    )
    return from_rows(readings, batch)


@njit(cache=True)
def fix_axis(true_value: float, noise: float, noise_std: float) -> float:
    """One axis of a positioning fix: the true value plus scaled standard normal noise."""
    return true_value + noise_std * noise


@vectorize(["float64(float64, float64, float64)"], cache=True)
def _fix_values(true_value: float, noise: float, noise_std: float) -> float:
    return fix_axis(true_value, noise, noise_std)


def fix_noise_std(params: PositioningParams) -> FloatArray:
    """The noise std of each axis of a fix (3,): x and y in metres, the heading in radians."""
    return np.array(
        [params.position_noise_std_m, params.position_noise_std_m, params.heading_noise_std_rad]
    )


def pose_fix(pose: FloatArray, noise: FloatArray, params: PositioningParams) -> FloatArray:
    """A positioning fix (..., 3) from the true pose and standard normal draws (..., 3)."""
    return np.asarray(_fix_values(pose, noise, fix_noise_std(params)), dtype=np.float64)

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

Round other robots the paper's field is not enough (DESIGN.md §7: a dead robot stays where it
stopped, as an obstacle, and the others keep going without collisions).  A body on a robot's
path that does not move out of its way (a stopped robot, or a live one that stays put in the
formation's frame while another rejoins its slot) is the field's local minimum: its repulsion
points straight back along the path, balances the pull of the reference, and the robot stalls
in front of it until the reference has moved past and pulls it through the body.  Two
additions, for robot sources only (the paper's scenario never brings two robots within ρ₀, so
its figures are unchanged):

* **Circulation** (`circulation`): each robot that repels adds a tangential force, its radial
  force turned by 90° and scaled by `circulation_ratio`, clipped on its own (the radial part
  keeps its full clip near contact).  Round a live robot it turns anticlockwise, so two robots
  that meet both turn the same way and pass.  Round a stopped one it turns to the side
  (`circulation_side`) where the robot's goal and the push of its other sources lean when the
  body begins to repel, and keeps that side while it repels: no chattering on the line through
  the body, and the side with room wins when the body stands next to an obstacle.
* **Keeping clear** (`keep_clear`): the offset's leak and a reference that runs into a body
  can still pull the desired point into it faster than the clipped repulsion pushes back.  So
  after the offset is updated, the desired point is moved out along the line from each robot
  that repels through this one, to at least two body radii plus a clearance, and the part of
  its velocity pointing back in is taken away.

**Approach guard** (`limit_approach`): the field shapes the path; it does not promise that a
robot never touches a body, and where several sources meet (the leader going round the obstacle
with a follower beside it, a robot rejoining past a braked one) it can leave a robot driving
into one. So the last step of the control law limits the commanded velocity itself, as a
control barrier function would: towards each body the robot knows of (a peer from the radio, an
obstacle point from the sonar) the gap may close at most at `budget = (gap - guard_gap_m) /
guard_time_constant_s`, so no faster than exponentially and never below `guard_gap_m` (a
negative budget backs the robot off). Towards a stopped body or an obstacle the robot's
approach speed is bounded by the whole budget. Towards a live robot it takes half (`share` 0.5:
the other one limits its own approach too), and less when the other one, by its broadcast
velocity, already approaches faster than its half: a robot whose motor runs away, or one that
does not guard, is kept off by the healthy one as far as it can. The robot keeps every other
motion, so it slides along the body instead of stopping, and stops where two bodies hem it in.
It acts only a few centimetres from a body at the robots' speeds: at 0.10 m and 0.25 s, 0.28
m/s is still allowed towards the obstacle. In the paper's scenario, whose closest pass is about
0.10 m, it cuts a follower's command for a moment as it passes the obstacle; the run's figures
move in the fourth digit.

`pair_force`, `circulation`, `circulation_side`, `keep_clear`, `limit_approach` and
`clip_vector` are the compiled scalar forms (numba) the control step's kernel calls;
`repulsive_force` and `clip_norm` are the array forms of the first and the last.
`repulsive_potential` (eq. 23 itself) is not part of the control step and stays in numpy, for
tests and readers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.kernels import njit
from robot_firmware.control.rows import as_rows, from_rows

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


@njit(cache=True)
def pair_force(
    gap_m: float, valid: bool, gain: float, influence_m: float, min_gap_m: float
) -> float:
    """Eq. 25 for one pair: the magnitude of the repulsion along the source-to-robot direction."""
    if not (valid and gap_m <= influence_m):
        return 0.0
    rho = max(gap_m, min_gap_m)
    return gain * (1.0 / rho - 1.0 / influence_m) / (rho * rho)


@njit(cache=True)
def circulation(direction_x: float, direction_y: float, magnitude: float) -> tuple[float, float]:
    """The tangential force round another robot: `magnitude` along the unit direction
    (direction_x, direction_y) from that robot to this one, turned anticlockwise by 90°
    (a negative magnitude turns it clockwise)."""
    return -magnitude * direction_y, magnitude * direction_x


@njit(cache=True)
def circulation_side(direction_x: float, direction_y: float, lean_x: float, lean_y: float) -> float:
    """Which way to go round a stopped robot: +1 anticlockwise, -1 clockwise, the side along
    which (lean_x, lean_y) points (anticlockwise when it has no tangential part)."""
    return 1.0 if -direction_y * lean_x + direction_x * lean_y >= 0.0 else -1.0


@njit(cache=True)
def keep_clear(
    from_source_x: float,
    from_source_y: float,
    rate_x: float,
    rate_y: float,
    direction_x: float,
    direction_y: float,
    reach_m: float,
) -> tuple[float, float]:
    """How a desired point is kept clear of another robot, along the unit direction
    (direction_x, direction_y) from that robot through this one.

    (from_source_x, from_source_y) is the desired point minus the other robot's position and
    (rate_x, rate_y) the desired velocity.  Returns how far to move the point along the
    direction so that it lies at least `reach_m` out, and the desired velocity's component
    along the direction if it points back in (<= 0; 0 otherwise), to take away."""
    along_m = from_source_x * direction_x + from_source_y * direction_y
    inward_mps = min(rate_x * direction_x + rate_y * direction_y, 0.0)
    return max(reach_m - along_m, 0.0), inward_mps


@njit(cache=True)
def limit_approach(
    vx: float,
    vy: float,
    direction_x: float,
    direction_y: float,
    gap_m: float,
    share: float,
    other_approach_mps: float,
    stop_gap_m: float,
    time_constant_s: float,
) -> tuple[float, float, bool]:
    """The approach guard for one body: a velocity (vx, vy) with its component towards the body
    (against the unit direction from the body to the robot) cut to at most the lesser of
    share · budget and budget - other_approach_mps, budget = (gap_m - stop_gap_m) /
    time_constant_s (other_approach_mps: how fast the body itself approaches this robot, 0 for
    one that does not move); and whether it was cut."""
    budget = (gap_m - stop_gap_m) / time_constant_s
    allowed = min(share * budget, budget - other_approach_mps)
    approach = -(vx * direction_x + vy * direction_y)
    if approach <= allowed:
        return vx, vy, False
    excess = approach - allowed
    return vx + excess * direction_x, vy + excess * direction_y, True


@njit(cache=True)
def clip_vector(x: float, y: float, max_norm: float) -> tuple[float, float]:
    """Scale a vector down to at most `max_norm`, keeping its direction."""
    scale = min(1.0, max_norm / max(math.hypot(x, y), 1e-12))
    return x * scale, y * scale


@njit(cache=True)
def _force_rows(
    direction: FloatArray, gap: FloatArray, valid: BoolArray, gain: float, influence_m: float,
    min_gap_m: float,
) -> FloatArray:  # fmt: skip
    out = np.zeros((gap.shape[0], 2))
    for i in range(gap.shape[0]):
        for j in range(gap.shape[1]):
            magnitude = pair_force(gap[i, j], valid[i, j], gain, influence_m, min_gap_m)
            out[i, 0] += magnitude * direction[i, j, 0]
            out[i, 1] += magnitude * direction[i, j, 1]
    return out


@njit(cache=True)
def _clip_rows(vector: FloatArray, max_norm: float) -> FloatArray:
    out = np.empty((vector.shape[0], 2))
    for i in range(vector.shape[0]):
        out[i, 0], out[i, 1] = clip_vector(vector[i, 0], vector[i, 1], max_norm)
    return out


def repulsive_force(
    direction_from_source: ArrayLike,
    gap_m: ArrayLike,
    valid: ArrayLike,
    gain: float,
    influence_m: float,
    min_gap_m: float,
) -> FloatArray:
    """Eq. 25 summed over sources.

    direction_from_source: (..., K, 2) unit vectors from each source's centre to the robot.
    gap_m: (..., K) body-to-body gaps.  valid: (..., K) which sources exist.
    Returns the force (..., 2) before clipping.
    """
    batch, rows = as_rows(
        (direction_from_source, 2, np.float64), (gap_m, 1, np.float64), (valid, 1, np.bool_)
    )
    arguments: list[Any] = [*rows, float(gain), float(influence_m), float(min_gap_m)]
    return from_rows(_force_rows(*arguments), batch)


def clip_norm(vector: ArrayLike, max_norm: float) -> FloatArray:
    """Scale vectors (..., 2) down to at most `max_norm`, keeping their direction."""
    batch, (rows,) = as_rows((vector, 1, np.float64))
    return from_rows(_clip_rows(rows, float(max_norm)), batch)

"""One control tick of a robot: 5C levels 2 (conversion), 3 (cyber) and 4 (cognition).

    conversion  odometry from encoder counts (eq. 11) fused with the positioning fix
    cyber       desired pose: the trajectory for the leader, eqs. 17-21 for a follower, from the
                leader's last broadcast state extrapolated to now; APF repulsion (eqs. 22-25)
                from peers' broadcast positions and from sonar echoes
    cognition   Table 2 fuzzy scheduler moves K_P, K_I, K_D (K = K₀ + η·ΔK), eq. 14 gives the
                wheel speeds, saturated

The function is pure and batched: every array has the same leading batch shape (one robot in
the firmware, (B, N) robots in the batch simulator), peers are a further axis P.

How the APF force enters eq. 14 is not stated in the paper (DESIGN.md §6).  Here it is a
bounded velocity added to Ẏ_d and integrated into an offset of Y_d that leaks back, so that the
PID law follows the avoidance instead of fighting it.  Inside a field the leak is slow (the
offset settles where the repulsion balances it, up to max speed x τ_hold, and the robot slides
around the source while its reference moves on); once the field is clear the offset is released
with a shorter τ_release.  The integrator is frozen while the field is active.

Round another robot the repulsion also turns (circulation) and the desired point is kept clear
of its body (apf.py): round a stopped robot (`ControlInputs.peer_stopped`: a dead one, braked
where it lost power) the side is chosen once per encounter and kept in
`ControllerState.circulation_side`.  Neither is in the paper, and neither acts in its scenario,
where no two robots come within the influence distance.

Sonar echoes that fall on a live peer whose position is known from the radio are left to the
robot-robot term, so a peer is not repelled twice; echoes on a stopped peer are kept, since its
position is only where it was last heard to coast to.

The tick is compiled (numba): `control_robots` runs it for a range of robots (`control_robot`
for one) from the compiled forms of each equation (kinematics, estimation, formation, apf,
fuzzy, pid), and `control_step` runs it over every robot of a batch, on every core when the
batch is large (`prange`).  The same kernel steers one robot in the firmware and B x N robots
in the batch simulator (services/sim/ticks.py calls `control_robots` for all of them at once).
tests/control/oracle.py states the same tick in numpy; the kernels are tested against it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt

from robot_firmware.control.apf import (
    circulation,
    circulation_side,
    clip_vector,
    keep_clear,
    limit_approach,
    pair_force,
)
from robot_firmware.control.estimation import (
    EstimatorState,
    fuse_fix,
    metres_per_count,
    odometry,
)
from robot_firmware.control.formation import slot_reference
from robot_firmware.control.fuzzy import FuzzyRuleBase, infer_one
from robot_firmware.control.kernels import njit, prange
from robot_firmware.control.kinematics import body_rate, rim_speeds
from robot_firmware.control.pid import PidState, axis_error, axis_error_rate, pid_law
from robot_firmware.control.rows import as_rows, from_rows, rows_of

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]
Vector3 = tuple[float, float, float]


def default_sonar_beam_angles_rad() -> tuple[float, ...]:
    """Twelve transducers every 30° around the body, the first looking forward."""
    return tuple(float(a) for a in np.deg2rad(np.arange(0.0, 360.0, 30.0)))


PositiveVector3 = tuple[PositiveFloat, PositiveFloat, PositiveFloat]


class ControllerParams(BaseModel):
    """Constants of the robot's control software (the firmware's configuration)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    control_period_s: PositiveFloat = 0.01
    wheel_base_m: PositiveFloat = 0.25
    wheel_radius_m: PositiveFloat = 0.0508
    body_radius_m: PositiveFloat = 0.3
    encoder_counts_per_rev: PositiveInt = 2048
    motor_no_load_speed_radps: PositiveFloat = 20.0
    max_wheel_speed_radps: PositiveFloat = 18.0
    kp: PositiveVector3 = (4.0, 4.0, 4.0)
    ki: tuple[float, float, float] = (2.0, 2.0, 2.0)
    kd: tuple[float, float, float] = (0.1, 0.1, 0.1)
    fuzzy_enabled: bool = True
    fuzzy_gain_fraction: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """η of K = K₀ + η·ΔK for (K_P, K_I, K_D), as a fraction of K₀; ΔK is on [-1, 1]."""
    error_scale: PositiveVector3 = (0.05, 0.05, 0.1)
    """e that maps to the outer fuzzy sets, per axis (m, m, rad)."""
    error_rate_scale: PositiveVector3 = (0.2, 0.2, 0.5)
    """ė that maps to the outer fuzzy sets, per axis (m/s, m/s, rad/s)."""
    integral_limit: PositiveVector3 = (0.1, 0.1, 0.1)
    derivative_filter_time_constant_s: float = Field(default=0.03, ge=0.0)
    apf_robot_gain: float = Field(default=0.005, ge=0.0)
    """ς₁ of eqs. 23 and 25, in m³/s: the force is used as a velocity."""
    apf_obstacle_gain: float = Field(default=0.005, ge=0.0)
    """ς₂ of eqs. 23 and 25, per sonar echo."""
    apf_influence_m: PositiveFloat = 0.4
    """ρ₀: the body-to-body gap below which a source repels."""
    apf_min_gap_m: PositiveFloat = 0.02
    apf_max_speed_mps: float = Field(default=0.8, ge=0.0)
    apf_circulation_ratio: float = Field(default=1.0, ge=0.0)
    """Tangential over radial repulsion round another robot (apf.py, `circulation`)."""
    apf_clearance_m: float = Field(default=0.1, ge=0.0)
    """The gap the desired point keeps from another robot's body (apf.py, `keep_clear`)."""
    approach_guard: bool = True
    """Limit the commanded approach speed towards every known body (apf.py, `limit_approach`)."""
    guard_gap_m: float = Field(default=0.03, ge=0.0)
    """The gap the approach guard keeps to every body the robot knows of."""
    guard_time_constant_s: PositiveFloat = 0.25
    """How fast the approach guard lets a gap close: at most (gap - guard_gap_m) / this."""
    avoidance_hold_time_constant_s: PositiveFloat = 1.5
    avoidance_release_time_constant_s: PositiveFloat = 0.4
    fix_gain: float = Field(default=0.3, gt=0.0, le=1.0)
    rate_filter_time_constant_s: float = Field(default=0.05, ge=0.0)
    peer_timeout_s: PositiveFloat = 1.0
    sonar_beam_angles_rad: tuple[float, ...] = Field(default_factory=default_sonar_beam_angles_rad)
    sonar_peer_margin_m: float = Field(default=0.15, ge=0.0)

    def model_copy(self, *, update: Mapping[str, Any] | None = None, deep: bool = False) -> Self:
        """A copy (pydantic's), without this one's `constants`: they are computed again from the
        copy's own fields."""
        copy = super().model_copy(update=update, deep=deep)
        copy.__dict__.pop("constants", None)
        return copy

    @cached_property
    def constants(self) -> ControlConstants:
        """These parameters as the compiled control step takes them (computed once)."""
        return ControlConstants(
            dt_s=float(self.control_period_s),
            wheel_base_m=float(self.wheel_base_m),
            wheel_radius_m=float(self.wheel_radius_m),
            body_radius_m=float(self.body_radius_m),
            metres_per_count=metres_per_count(self.wheel_radius_m, self.encoder_counts_per_rev),
            no_load_radps=float(self.motor_no_load_speed_radps),
            max_wheel_radps=float(self.max_wheel_speed_radps),
            fuzzy_enabled=bool(self.fuzzy_enabled),
            derivative_tau_s=float(self.derivative_filter_time_constant_s),
            robot_gain=float(self.apf_robot_gain),
            obstacle_gain=float(self.apf_obstacle_gain),
            influence_m=float(self.apf_influence_m),
            min_gap_m=float(self.apf_min_gap_m),
            max_repulsion_mps=float(self.apf_max_speed_mps),
            circulation_ratio=float(self.apf_circulation_ratio),
            clearance_m=float(self.apf_clearance_m),
            guard_enabled=bool(self.approach_guard),
            guard_gap_m=float(self.guard_gap_m),
            guard_tau_s=float(self.guard_time_constant_s),
            hold_tau_s=float(self.avoidance_hold_time_constant_s),
            release_tau_s=float(self.avoidance_release_time_constant_s),
            fix_gain=float(self.fix_gain),
            rate_tau_s=float(self.rate_filter_time_constant_s),
            peer_timeout_s=float(self.peer_timeout_s),
            sonar_peer_margin_m=float(self.sonar_peer_margin_m),
            axis=np.array(
                [
                    self.kp,
                    self.ki,
                    self.kd,
                    self.fuzzy_gain_fraction,
                    self.error_scale,
                    self.error_rate_scale,
                    self.integral_limit,
                ],
                dtype=np.float64,
            ),
            beam_angles_rad=np.asarray(self.sonar_beam_angles_rad, dtype=np.float64),
        )


class ControlConstants(NamedTuple):
    """`ControllerParams` as the kernel reads them: floats, and arrays of the per-axis ones.

    axis rows: K_P₀, K_I₀, K_D₀, η, error scale, error-rate scale, integral limit (7, 3).
    """

    dt_s: float
    wheel_base_m: float
    wheel_radius_m: float
    body_radius_m: float
    metres_per_count: float
    no_load_radps: float
    max_wheel_radps: float
    fuzzy_enabled: bool
    derivative_tau_s: float
    robot_gain: float
    obstacle_gain: float
    influence_m: float
    min_gap_m: float
    max_repulsion_mps: float
    circulation_ratio: float
    clearance_m: float
    guard_enabled: bool
    guard_gap_m: float
    guard_tau_s: float
    hold_tau_s: float
    release_tau_s: float
    fix_gain: float
    rate_tau_s: float
    peer_timeout_s: float
    sonar_peer_margin_m: float
    axis: FloatArray
    beam_angles_rad: FloatArray


AXIS_KP, AXIS_KI, AXIS_KD, AXIS_ETA, AXIS_ERROR_SCALE, AXIS_RATE_SCALE, AXIS_INTEGRAL_LIMIT = range(
    7
)


@dataclass(frozen=True)
class RobotRole:
    """Who a robot is in the formation: leader, or follower with its slot (eq. 17)."""

    is_leader: BoolArray
    slot_distance_m: FloatArray
    slot_angle_rad: FloatArray


@dataclass(frozen=True)
class ControllerState:
    """What a robot's control software remembers between ticks.

    echo_points_m / echo_valid (..., S, 2) / (..., S): the obstacle points of the last sonar
    sweep in world coordinates, kept until the next sweep.  circulation_side (..., P): the side
    (+1 anticlockwise, -1 clockwise, 0 none) the robot goes round each stopped peer that repels
    it, kept while it repels (apf.py, `circulation`); None: no side chosen yet.
    """

    estimator: EstimatorState
    pid: PidState
    avoidance_offset_m: FloatArray
    echo_points_m: FloatArray
    echo_valid: BoolArray
    circulation_side: FloatArray | None = None

    @staticmethod
    def initial(batch_shape: tuple[int, ...], sonar_count: int) -> ControllerState:
        return ControllerState(
            estimator=EstimatorState.unlocalised(batch_shape),
            pid=PidState.zeros(batch_shape),
            avoidance_offset_m=np.zeros(batch_shape + (2,)),
            echo_points_m=np.zeros(batch_shape + (sonar_count, 2)),
            echo_valid=np.zeros(batch_shape + (sonar_count,), dtype=bool),
        )


@dataclass(frozen=True)
class ControlInputs:
    """What the firmware has read by the start of a tick.

    sonar_range_m is the latest gap reading of each transducer (inf: no echo), and
    sonar_fresh says whether it arrived since the previous tick.  peer_* arrays
    hold the last state each peer broadcast and when it was stamped; reference_* is the
    trajectory at t_s (used by the leader only).  peer_stopped marks the peers known to have
    stopped for good (a dead robot's braked body, held at its last pose): the robot goes round
    them (apf.py, `circulation`); None: no peer is.
    """

    t_s: float
    encoder_counts: IntArray
    fix_pose: FloatArray
    fix_valid: BoolArray
    sonar_range_m: FloatArray
    sonar_fresh: bool
    peer_pose: FloatArray
    peer_rate: FloatArray
    peer_stamp_s: FloatArray
    peer_valid: BoolArray
    peer_is_leader: BoolArray
    reference_pose: FloatArray
    reference_rate: FloatArray
    peer_stopped: BoolArray | None = None


@dataclass(frozen=True)
class ControlOutputs:
    wheel_speed_radps: FloatArray
    duty: FloatArray
    desired_pose: FloatArray
    desired_rate: FloatArray
    error: FloatArray
    delta_k: FloatArray
    kp: FloatArray
    ki: FloatArray
    kd: FloatArray
    repulsion_mps: FloatArray
    active: BoolArray


@njit(cache=True)
def beam_point(
    x_m: float,
    y_m: float,
    theta_rad: float,
    beam_angle_rad: float,
    gap_m: float,
    body_radius_m: float,
) -> tuple[float, float]:
    """The world point at `gap_m` from the body's rim along one transducer's beam."""
    beam_world = theta_rad + beam_angle_rad
    reach = body_radius_m + gap_m
    return x_m + reach * math.cos(beam_world), y_m + reach * math.sin(beam_world)


@njit(cache=True)
def _beam_rows(
    pose: FloatArray, gap: FloatArray, beam_angles_rad: FloatArray, body_radius_m: float
) -> FloatArray:
    out = np.empty((pose.shape[0], beam_angles_rad.shape[0], 2))
    for i in range(pose.shape[0]):
        for j in range(beam_angles_rad.shape[0]):
            out[i, j, 0], out[i, j, 1] = beam_point(
                pose[i, 0], pose[i, 1], pose[i, 2], beam_angles_rad[j], gap[i, j], body_radius_m
            )
    return out


def sonar_beam_points(
    pose: ArrayLike, sonar_range_m: ArrayLike, params: ControllerParams
) -> FloatArray:
    """World points (..., S, 2) at ``sonar_range_m`` (finite, from the body's rim) along each
    transducer's beam of a robot at ``pose`` (..., 3): where its sonar ring says echoes are."""
    batch, (p, gap) = as_rows((pose, 1, np.float64), (sonar_range_m, 1, np.float64))
    k = params.constants
    return from_rows(_beam_rows(p, gap, k.beam_angles_rad, k.body_radius_m), batch)


@njit(cache=True, allocates=False)
def control_robots(
    first: int,
    stop: int,
    k: ControlConstants,
    t_s: float,
    sonar_fresh: bool,
    state_f: tuple,
    state_b: tuple,
    inputs_f: tuple,
    inputs_b: tuple,
    rules: tuple,
    out_f: tuple,
    out_b: tuple,
    scratch_ok: BoolArray,
    scratch_pose: FloatArray,
    origin: FloatArray,
) -> None:
    """One tick of robots (rows) first .. stop - 1: levels 2-4, writing their rows of every
    output array (the arrays are unpacked once for all of them).

    scratch_ok (R, P) and scratch_pose (R, P, 3) hold the peers seen this tick; origin is a
    zero pose, the leader's while none is heard.  It makes no array of its own (rows are copied
    element by element), so numba compiles it without its memory runtime and its row views
    cost no reference counting (`kernels.njit`'s `allocates=False`).
    """
    pose_in, rate_in, integral_in, previous_error, rate_prev, offset_in, echo_in, side_in = state_f
    previous_counts, localised_in, saturated_in, started_in, echo_valid_in = state_b
    (
        fix_pose,
        sonar_range,
        peer_pose_in,
        peer_rate,
        peer_stamp,
        reference_pose,
        reference_rate,
        slot_distance,
        slot_angle,
    ) = inputs_f
    counts, fix_valid, peer_valid, peer_is_leader, peer_stopped, is_leader = inputs_b
    error_centres, rate_centres, error_count, rate_count, rule_outputs = rules
    (pose, rate, integral, error, error_rate, offset, echo_points, side_out, wheel, duty,
     desired, desired_rate, delta_k, kp, ki, kd, repulsion) = out_f  # fmt: skip
    previous_counts_out, localised, saturated, started, echo_valid, active_out = out_b

    for i in range(first, stop):
        # Level 2: odometry (eq. 11) and the positioning fix.
        odometry(
            pose_in[i], rate_in[i], previous_counts[i], counts[i], k.dt_s, k.metres_per_count,
            k.wheel_base_m, k.rate_tau_s, pose[i], rate[i],
        )  # fmt: skip
        for w in range(4):
            previous_counts_out[i, w] = counts[i, w]
        localised[i] = fuse_fix(pose[i], localised_in[i], fix_pose[i], fix_valid[i], k.fix_gain)
        x = pose[i, 0]
        y = pose[i, 1]
        theta = pose[i, 2]

        # Level 3: peers extrapolated to now, the leader, and the desired pose.
        peers = peer_stamp.shape[1]
        peer_ok = scratch_ok[i]
        peer_pose = scratch_pose[i]
        leader = -1
        for j in range(peers):
            age_s = t_s - peer_stamp[i, j]
            peer_ok[j] = peer_valid[i, j] and age_s <= k.peer_timeout_s
            lead_time_s = max(age_s, 0.0) if peer_ok[j] else 0.0
            for a in range(3):
                peer_pose[j, a] = peer_pose_in[i, j, a] + peer_rate[i, j, a] * lead_time_s
            if leader < 0 and peer_ok[j] and peer_is_leader[i, j]:
                leader = j
        if is_leader[i]:
            for a in range(3):
                desired[i, a] = reference_pose[i, a]
                desired_rate[i, a] = reference_rate[i, a]
        else:
            # No leader heard: the slot of a leader at the origin (the robot stays inactive).
            leader_pose = peer_pose[leader] if leader >= 0 else origin
            leader_rate = peer_rate[i, leader] if leader >= 0 else origin
            slot_reference(
                leader_pose, leader_rate, pose[i], slot_distance[i], slot_angle[i], desired[i],
                desired_rate[i],
            )  # fmt: skip

        # Level 3: APF (eq. 25) from peers (radio) and from sonar echoes not explained by a peer.
        # Sources that do not repel (pair_force 0) are skipped: they would add exactly nothing.
        force_x = 0.0
        force_y = 0.0
        for j in range(peers):
            if not peer_ok[j]:
                continue
            dx = x - peer_pose[j, 0]
            dy = y - peer_pose[j, 1]
            centre_gap = math.hypot(dx, dy)
            reach = max(centre_gap, 1e-9)
            magnitude = pair_force(
                centre_gap - 2.0 * k.body_radius_m, peer_ok[j], k.robot_gain, k.influence_m,
                k.min_gap_m,
            )  # fmt: skip
            force_x += magnitude * (dx / reach)
            force_y += magnitude * (dy / reach)
        beams = k.beam_angles_rad.shape[0]
        if sonar_fresh:
            near_peer_m = k.body_radius_m + k.sonar_peer_margin_m
            for s in range(beams):
                gap = sonar_range[i, s]
                echo = math.isfinite(gap) and gap <= k.influence_m
                px, py = beam_point(
                    x, y, theta, k.beam_angles_rad[s], gap if echo else 0.0, k.body_radius_m
                )
                echo_points[i, s, 0] = px
                echo_points[i, s, 1] = py
                explained = False
                for j in range(peers):
                    if echo and peer_ok[j] and not peer_stopped[i, j] and not explained:
                        explained = (
                            math.hypot(px - peer_pose[j, 0], py - peer_pose[j, 1]) < near_peer_m
                        )
                echo_valid[i, s] = echo and not explained
        else:
            for s in range(beams):
                echo_points[i, s, 0] = echo_in[i, s, 0]
                echo_points[i, s, 1] = echo_in[i, s, 1]
                echo_valid[i, s] = echo_valid_in[i, s]
        echo_x = 0.0
        echo_y = 0.0
        for s in range(beams):
            if not echo_valid[i, s]:
                continue
            dx = x - echo_points[i, s, 0]
            dy = y - echo_points[i, s, 1]
            distance = math.hypot(dx, dy)
            reach = max(distance, 1e-9)
            magnitude = pair_force(
                distance - k.body_radius_m, echo_valid[i, s], k.obstacle_gain, k.influence_m,
                k.min_gap_m,
            )  # fmt: skip
            echo_x += magnitude * (dx / reach)
            echo_y += magnitude * (dy / reach)

        # Level 3: the tangential part round each robot that repels (apf.py, `circulation`): round
        # a stopped one to the side chosen when it began to repel, where the goal (the way the
        # reference moves plus its lead over the robot, closed in one hold time constant) and the
        # other sources' push lean; round a live one anticlockwise.
        goal_x = desired_rate[i, 0] + (desired[i, 0] - x) / k.hold_tau_s
        goal_y = desired_rate[i, 1] + (desired[i, 1] - y) / k.hold_tau_s
        turn_x = 0.0
        turn_y = 0.0
        for j in range(peers):
            side_out[i, j] = 0.0
            if not peer_ok[j]:
                continue
            dx = x - peer_pose[j, 0]
            dy = y - peer_pose[j, 1]
            centre_gap = math.hypot(dx, dy)
            reach = max(centre_gap, 1e-9)
            magnitude = pair_force(
                centre_gap - 2.0 * k.body_radius_m, peer_ok[j], k.robot_gain, k.influence_m,
                k.min_gap_m,
            )  # fmt: skip
            if magnitude == 0.0:
                continue
            ux = dx / reach
            uy = dy / reach
            side = 1.0
            if peer_stopped[i, j]:
                side = side_in[i, j]
                if side == 0.0:
                    lean_x = goal_x + force_x + echo_x - magnitude * ux
                    lean_y = goal_y + force_y + echo_y - magnitude * uy
                    side = circulation_side(ux, uy, lean_x, lean_y)
                side_out[i, j] = side
            tangent_x, tangent_y = circulation(ux, uy, side * k.circulation_ratio * magnitude)
            turn_x += tangent_x
            turn_y += tangent_y
        rx, ry = clip_vector(force_x + echo_x, force_y + echo_y, k.max_repulsion_mps)
        tx, ty = clip_vector(turn_x, turn_y, k.circulation_ratio * k.max_repulsion_mps)
        rx += tx
        ry += ty
        repulsion[i, 0] = rx
        repulsion[i, 1] = ry
        avoiding = rx != 0.0 or ry != 0.0
        leak_tau_s = k.hold_tau_s if avoiding else k.release_tau_s
        for a in range(2):
            offset_rate = repulsion[i, a] - offset_in[i, a] / leak_tau_s
            offset[i, a] = offset_in[i, a] + offset_rate * k.dt_s
            desired[i, a] += offset[i, a]
            desired_rate[i, a] += offset_rate
        # Level 3: the desired point stays clear of every robot that repels (apf.py, `keep_clear`).
        for j in range(peers):
            if not peer_ok[j]:
                continue
            dx = x - peer_pose[j, 0]
            dy = y - peer_pose[j, 1]
            centre_gap = math.hypot(dx, dy)
            if centre_gap - 2.0 * k.body_radius_m > k.influence_m:
                continue
            reach = max(centre_gap, 1e-9)
            ux = dx / reach
            uy = dy / reach
            push_m, inward_mps = keep_clear(
                desired[i, 0] - peer_pose[j, 0], desired[i, 1] - peer_pose[j, 1],
                desired_rate[i, 0], desired_rate[i, 1], ux, uy,
                2.0 * k.body_radius_m + k.clearance_m,
            )  # fmt: skip
            offset[i, 0] += push_m * ux
            offset[i, 1] += push_m * uy
            desired[i, 0] += push_m * ux
            desired[i, 1] += push_m * uy
            desired_rate[i, 0] -= inward_mps * ux
            desired_rate[i, 1] -= inward_mps * uy

        # Level 4: fuzzy-scheduled gains (Table 2, eqs. 6-7) and the redundant PID law (eq. 14).
        axis_error(pose[i], desired[i], error[i])
        axis_error_rate(
            error[i], previous_error[i], rate_prev[i], started_in[i], k.dt_s, k.derivative_tau_s,
            error_rate[i],
        )  # fmt: skip
        g = k.axis
        for a in range(3):
            if k.fuzzy_enabled:
                delta_k[i, a] = infer_one(
                    error_centres[i], rate_centres[i], error_count[i], rate_count[i],
                    rule_outputs[i], error[i, a] / g[AXIS_ERROR_SCALE, a],
                    error_rate[i, a] / g[AXIS_RATE_SCALE, a],
                )  # fmt: skip
            else:
                delta_k[i, a] = 0.0
            kp[i, a] = g[AXIS_KP, a] * (1.0 + g[AXIS_ETA, a] * delta_k[i, a])
            ki[i, a] = g[AXIS_KI, a] * (1.0 + g[AXIS_ETA, a] * delta_k[i, a])
            kd[i, a] = g[AXIS_KD, a] * (1.0 + g[AXIS_ETA, a] * delta_k[i, a])
        active = localised[i] and (is_leader[i] or leader >= 0)
        active_out[i] = active
        saturated[i] = pid_law(
            integral_in[i], saturated_in[i], error[i], error_rate[i], desired_rate[i], theta,
            kp[i], ki[i], kd[i], active and not avoiding, k.dt_s, g[AXIS_INTEGRAL_LIMIT],
            k.wheel_base_m, k.wheel_radius_m, k.max_wheel_radps, integral[i], wheel[i],
        )  # fmt: skip
        started[i] = True
        # Level 4: the approach guard (apf.py, `limit_approach`) on the commanded velocity,
        # towards every peer and every sonar echo not explained by a live peer.
        if active and k.guard_enabled:
            vx, vy, spin = body_rate(
                wheel[i, 0] * k.wheel_radius_m, wheel[i, 1] * k.wheel_radius_m,
                wheel[i, 2] * k.wheel_radius_m, wheel[i, 3] * k.wheel_radius_m, theta,
                k.wheel_base_m,
            )  # fmt: skip
            guarded = False
            for _ in range(2):  # the bounds one after the other, twice over
                for j in range(peers):
                    if not peer_ok[j]:
                        continue
                    dx = x - peer_pose[j, 0]
                    dy = y - peer_pose[j, 1]
                    centre_gap = math.hypot(dx, dy)
                    reach = max(centre_gap, 1e-9)
                    ux = dx / reach
                    uy = dy / reach
                    vx, vy, cut = limit_approach(
                        vx, vy, ux, uy, centre_gap - 2.0 * k.body_radius_m,
                        1.0 if peer_stopped[i, j] else 0.5,
                        peer_rate[i, j, 0] * ux + peer_rate[i, j, 1] * uy, k.guard_gap_m,
                        k.guard_tau_s,
                    )  # fmt: skip
                    guarded = guarded or cut
                for s in range(beams):
                    if not echo_valid[i, s]:
                        continue
                    dx = x - echo_points[i, s, 0]
                    dy = y - echo_points[i, s, 1]
                    distance = math.hypot(dx, dy)
                    reach = max(distance, 1e-9)
                    vx, vy, cut = limit_approach(
                        vx, vy, dx / reach, dy / reach, distance - k.body_radius_m, 1.0, 0.0,
                        k.guard_gap_m, k.guard_tau_s,
                    )  # fmt: skip
                    guarded = guarded or cut
            if guarded:
                rims = rim_speeds(vx, vy, spin, theta, k.wheel_base_m)
                peak = 0.0
                for w in range(4):
                    wheel[i, w] = rims[w] / k.wheel_radius_m
                    peak = max(peak, abs(wheel[i, w]))
                scale = max(peak / k.max_wheel_radps, 1.0)
                for w in range(4):
                    wheel[i, w] = wheel[i, w] / scale
                saturated[i] = True  # anti-windup: the law's command was not carried out
        for w in range(4):
            if not active:
                wheel[i, w] = 0.0
            duty[i, w] = min(max(wheel[i, w] / k.no_load_radps, -1.0), 1.0)


@njit(cache=True)
def control_robot(
    i: int,
    k: ControlConstants,
    t_s: float,
    sonar_fresh: bool,
    state_f: tuple,
    state_b: tuple,
    inputs_f: tuple,
    inputs_b: tuple,
    rules: tuple,
    out_f: tuple,
    out_b: tuple,
    scratch_ok: BoolArray,
    scratch_pose: FloatArray,
    origin: FloatArray,
) -> None:
    """One tick of robot (row) i (`control_robots` for that row alone)."""
    control_robots(
        i, i + 1, k, t_s, sonar_fresh, state_f, state_b, inputs_f, inputs_b, rules, out_f, out_b,
        scratch_ok, scratch_pose, origin,
    )  # fmt: skip


def _make_control_rows(parallel: bool):  # type: ignore[no-untyped-def]
    def control_rows(k, t_s, sonar_fresh, state_f, state_b, inputs_f, inputs_b, rules):  # type: ignore[no-untyped-def]
        n = state_f[0].shape[0]
        beams = k.beam_angles_rad.shape[0]
        peers = inputs_f[4].shape[1]
        out_f = (
            np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty((n, 3)), np.empty((n, 2)), np.empty((n, beams, 2)), np.empty((n, peers)),
            np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty((n, 2)),
        )  # fmt: skip
        out_b = (
            np.empty((n, 4), dtype=np.int64), np.empty(n, dtype=np.bool_),
            np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.bool_),
            np.empty((n, beams), dtype=np.bool_), np.empty(n, dtype=np.bool_),
        )  # fmt: skip
        scratch_ok = np.empty((n, peers), dtype=np.bool_)
        scratch_pose = np.empty((n, peers, 3))
        origin = np.zeros(3)
        for i in prange(n):
            control_robot(
                i, k, t_s, sonar_fresh, state_f, state_b, inputs_f, inputs_b, rules, out_f,
                out_b, scratch_ok, scratch_pose, origin,
            )  # fmt: skip
        return out_f, out_b

    return njit(cache=True, parallel=parallel)(control_rows)


_control_rows_serial = _make_control_rows(parallel=False)
_control_rows_parallel = _make_control_rows(parallel=True)
PARALLEL_MIN_ROBOTS = 64
"""Batches of at least this many robots run the control step on every core (numba prange)."""


def control_step(
    state: ControllerState,
    inputs: ControlInputs,
    role: RobotRole,
    rule_base: FuzzyRuleBase,
    params: ControllerParams,
) -> tuple[ControllerState, ControlOutputs]:
    """Advance one control period; returns the new state and the wheel commands.

    Every array broadcasts against the robots' batch shape (the state's); `rule_base` is one
    scheduler per robot (its batch axes broadcast the same way) used for all three axes.
    """
    est, pid = state.estimator, state.pid
    f8, i8, b1 = np.float64, np.int64, np.bool_
    batch = est.pose.shape[:-1]
    peer_shape = np.broadcast_shapes(batch + (1,), np.shape(inputs.peer_valid))
    stopped = (
        np.zeros(peer_shape, dtype=bool) if inputs.peer_stopped is None else inputs.peer_stopped
    )
    side = np.zeros(peer_shape) if state.circulation_side is None else state.circulation_side
    rows = rows_of(
        batch,
        (est.pose, 1, f8), (est.rate, 1, f8), (pid.integral, 1, f8),
        (pid.previous_error, 1, f8), (pid.error_rate, 1, f8), (state.avoidance_offset_m, 1, f8),
        (state.echo_points_m, 2, f8), (side, 1, f8),
        (est.previous_counts, 1, i8), (est.localised, 0, b1), (pid.saturated, 0, b1),
        (pid.started, 0, b1), (state.echo_valid, 1, b1),
        (inputs.fix_pose, 1, f8), (inputs.sonar_range_m, 1, f8), (inputs.peer_pose, 2, f8),
        (inputs.peer_rate, 2, f8), (inputs.peer_stamp_s, 1, f8), (inputs.reference_pose, 1, f8),
        (inputs.reference_rate, 1, f8), (role.slot_distance_m, 0, f8),
        (role.slot_angle_rad, 0, f8),
        (inputs.encoder_counts, 1, i8), (inputs.fix_valid, 0, b1), (inputs.peer_valid, 1, b1),
        (inputs.peer_is_leader, 1, b1), (stopped, 1, b1), (role.is_leader, 0, b1),
        (rule_base.error_centres, 1, f8), (rule_base.rate_centres, 1, f8),
        (rule_base.error_set_count, 0, i8), (rule_base.rate_set_count, 0, i8),
        (rule_base.rule_outputs, 2, f8),
    )  # fmt: skip
    robots = rows[0].shape[0]
    kernel = _control_rows_parallel if robots >= PARALLEL_MIN_ROBOTS else _control_rows_serial
    out_f, out_b = kernel(
        params.constants, float(inputs.t_s), bool(inputs.sonar_fresh),
        tuple(rows[0:8]), tuple(rows[8:13]), tuple(rows[13:22]), tuple(rows[22:28]),
        tuple(rows[28:33]),
    )  # fmt: skip
    (pose, rate, integral, error, error_rate, offset, echo_points, side_out, wheel, duty,
     desired, desired_rate, delta_k, kp, ki, kd, repulsion) = (
        from_rows(a, batch) for a in out_f
    )  # fmt: skip
    previous_counts, localised, saturated, started, echo_valid, active = (
        from_rows(a, batch) for a in out_b
    )
    new_state = ControllerState(
        estimator=EstimatorState(
            pose=pose, rate=rate, previous_counts=previous_counts, localised=localised
        ),
        pid=PidState(
            integral=integral,
            previous_error=error,
            error_rate=error_rate,
            saturated=saturated,
            started=started,
        ),
        avoidance_offset_m=offset,
        echo_points_m=echo_points,
        echo_valid=echo_valid,
        circulation_side=side_out,
    )
    outputs = ControlOutputs(
        wheel_speed_radps=wheel,
        duty=duty,
        desired_pose=desired,
        desired_rate=desired_rate,
        error=error,
        delta_k=delta_k,
        kp=kp,
        ki=ki,
        kd=kd,
        repulsion_mps=repulsion,
        active=active,
    )
    return new_state, outputs


def output_rows(
    rows: int, beams: int, peers: int
) -> tuple[tuple[FloatArray, ...], tuple[NDArray[Any], ...]]:
    """Zeroed arrays for `control_robots`' outputs (out_f, out_b) of `rows` robots, the first
    eight and five of which are a state set: the next tick reads them as state_f and state_b."""
    floats = (
        (3,), (3,), (3,), (3,), (3,), (2,), (beams, 2), (peers,), (4,), (4,), (3,), (3,), (3,),
        (3,), (3,), (3,), (2,),
    )  # fmt: skip
    flags = ((4,), (), (), (), (beams,), ())
    return (
        tuple(np.zeros((rows,) + core) for core in floats),
        tuple(
            np.zeros((rows,) + core, dtype=np.int64 if i == 0 else np.bool_)
            for i, core in enumerate(flags)
        ),
    )


class OneRobotControl:
    """`control_step` for one robot, on arrays made once: what the firmware runs every tick.

    `control_step` takes any batch of robots and returns new arrays; for a single robot each
    call would spend most of its time laying out some forty small arrays as rows, allocating
    twenty-three outputs and wrapping them again.  Here the rows are made once: the firmware
    writes the tick's inputs into `inputs` (views of the kernel's input rows) and calls `step`,
    which runs the same compiled `control_robots` on them.  The controller's state lives in two
    sets of arrays used in turn, as in the batch simulator (services/sim/ticks.py): a tick reads
    `state` (views of one set) and writes the other, which becomes `state`.  The results are
    `control_step`'s, bit for bit (tests/control/test_one_robot_control.py).

    `outputs` and `state` are views: valid until the tick after next overwrites their set.
    """

    def __init__(self, params: ControllerParams, peers: int, rule_base: FuzzyRuleBase) -> None:
        self.params = params
        self.constants = params.constants
        beams = len(params.sonar_beam_angles_rad)
        i8, b1 = np.int64, np.bool_

        self._sets = (output_rows(1, beams, peers), output_rows(1, beams, peers))
        self._reads = tuple((f[:8], b[:5]) for f, b in self._sets)
        """Each set's state_f and state_b, as the kernel reads them."""
        self._current = 0
        self._inputs_f = (
            np.zeros((1, 3)), np.full((1, beams), np.inf), np.zeros((1, peers, 3)),
            np.zeros((1, peers, 3)), np.full((1, peers), -np.inf), np.zeros((1, 3)),
            np.zeros((1, 3)), np.zeros(1), np.zeros(1),
        )  # fmt: skip
        self._inputs_b = (
            np.zeros((1, 4), dtype=i8), np.zeros(1, dtype=b1), np.zeros((1, peers), dtype=b1),
            np.zeros((1, peers), dtype=b1), np.zeros((1, peers), dtype=b1),
            np.zeros(1, dtype=b1),
        )  # fmt: skip
        self._scratch_ok = np.zeros((1, peers), dtype=b1)
        self._scratch_pose = np.zeros((1, peers, 3))
        self._origin = np.zeros(3)
        f, b = self._inputs_f, self._inputs_b
        self.inputs = ControlInputs(
            t_s=0.0,
            encoder_counts=b[0][0],
            fix_pose=f[0][0],
            fix_valid=b[1].reshape(()),
            sonar_range_m=f[1][0],
            sonar_fresh=False,
            peer_pose=f[2][0],
            peer_rate=f[3][0],
            peer_stamp_s=f[4][0],
            peer_valid=b[2][0],
            peer_is_leader=b[3][0],
            reference_pose=f[5][0],
            reference_rate=f[6][0],
            peer_stopped=b[4][0],
        )
        """The tick's inputs, to write in place (`t_s` and `sonar_fresh` go to `step`)."""
        self.peer_stopped: BoolArray = b[4][0]
        """`inputs.peer_stopped` (never None here)."""
        self.role = RobotRole(
            is_leader=b[5].reshape(()),
            slot_distance_m=f[7].reshape(()),
            slot_angle_rad=f[8].reshape(()),
        )
        """This tick's role, to write in place."""
        self._views = tuple(self._views_of(s) for s in self._sets)
        self.set_rule_base(rule_base)
        self.reset(np.zeros(4, dtype=np.int64))

    @staticmethod
    def _views_of(
        state_set: tuple[tuple[FloatArray, ...], tuple[NDArray[Any], ...]],
    ) -> tuple[ControllerState, ControlOutputs]:
        f, b = state_set
        state = ControllerState(
            estimator=EstimatorState(
                pose=f[0][0], rate=f[1][0], previous_counts=b[0][0], localised=b[1].reshape(())
            ),
            pid=PidState(
                integral=f[2][0],
                previous_error=f[3][0],
                error_rate=f[4][0],
                saturated=b[2].reshape(()),
                started=b[3].reshape(()),
            ),
            avoidance_offset_m=f[5][0],
            echo_points_m=f[6][0],
            echo_valid=b[4][0],
            circulation_side=f[7][0],
        )
        outputs = ControlOutputs(
            wheel_speed_radps=f[8][0], duty=f[9][0], desired_pose=f[10][0],
            desired_rate=f[11][0], error=f[3][0], delta_k=f[12][0], kp=f[13][0], ki=f[14][0],
            kd=f[15][0], repulsion_mps=f[16][0], active=b[5].reshape(()),
        )  # fmt: skip
        return state, outputs

    @property
    def state(self) -> ControllerState:
        """What the next `step` starts from."""
        return self._views[self._current][0]

    def set_rule_base(self, rule_base: FuzzyRuleBase) -> None:
        """One scheduler for the three axes, from the next `step` on."""
        f8, i8 = np.float64, np.int64
        rows = rows_of(
            (),
            (rule_base.error_centres, 1, f8), (rule_base.rate_centres, 1, f8),
            (rule_base.error_set_count, 0, i8), (rule_base.rate_set_count, 0, i8),
            (rule_base.rule_outputs, 2, f8),
        )  # fmt: skip
        self._rules = tuple(np.ascontiguousarray(a) for a in rows)

    def reset(self, previous_counts: ArrayLike) -> None:
        """The initial state (`ControllerState.initial`), encoders counted from
        `previous_counts`: the next `step` starts from it."""
        f, b = self._sets[self._current]
        for array in f[:8]:
            array[...] = 0.0
        b[0][0] = previous_counts
        for array in b[1:5]:
            array[...] = False

    def load(self, state: ControllerState) -> None:
        """Start the next `step` from `state` (one robot's, as `control_step` returns it)."""
        est, pid = state.estimator, state.pid
        side = state.circulation_side
        f, b = self._sets[self._current]
        for target, value in zip(
            f[:8] + b[:5],
            (
                est.pose, est.rate, pid.integral, pid.previous_error, pid.error_rate,
                state.avoidance_offset_m, state.echo_points_m, 0.0 if side is None else side,
                est.previous_counts, est.localised, pid.saturated, pid.started, state.echo_valid,
            ),
            strict=True,
        ):  # fmt: skip
            target[0] = value

    def step(self, t_s: float, sonar_fresh: bool) -> ControlOutputs:
        """One control period on `inputs` and `role` from `state`; returns the outputs."""
        read_f, read_b = self._reads[self._current]
        written = 1 - self._current
        write_f, write_b = self._sets[written]
        control_robots(
            0, 1, self.constants, t_s, sonar_fresh, read_f, read_b, self._inputs_f,
            self._inputs_b, self._rules, write_f, write_b, self._scratch_ok, self._scratch_pose,
            self._origin,
        )  # fmt: skip
        self._current = written
        return self._views[written][1]

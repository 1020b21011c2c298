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

Sonar echoes that fall on a peer whose position is known from the radio are left to the
robot-robot term, so a peer is not repelled twice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt

from robot_firmware.control.apf import clip_norm, repulsive_force
from robot_firmware.control.estimation import EstimatorState, fuse_pose_fix, odometry_update
from robot_firmware.control.formation import follower_reference
from robot_firmware.control.fuzzy import FuzzyRuleBase, infer
from robot_firmware.control.pid import (
    PidState,
    filtered_error_rate,
    redundant_pid_law,
    tracking_error,
)

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

    model_config = ConfigDict(extra="forbid", frozen=True)

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
    avoidance_hold_time_constant_s: PositiveFloat = 1.5
    avoidance_release_time_constant_s: PositiveFloat = 0.4
    fix_gain: float = Field(default=0.3, gt=0.0, le=1.0)
    rate_filter_time_constant_s: float = Field(default=0.05, ge=0.0)
    peer_timeout_s: PositiveFloat = 1.0
    sonar_beam_angles_rad: tuple[float, ...] = Field(default_factory=default_sonar_beam_angles_rad)
    sonar_peer_margin_m: float = Field(default=0.15, ge=0.0)

    def gains(self, delta_k: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """K_P, K_I, K_D (..., 3) for a fuzzy output ΔK (..., 3)."""
        fp, fi, fd = self.fuzzy_gain_fraction
        kp = np.asarray(self.kp)
        ki = np.asarray(self.ki)
        kd = np.asarray(self.kd)
        return kp * (1.0 + fp * delta_k), ki * (1.0 + fi * delta_k), kd * (1.0 + fd * delta_k)


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
    sweep in world coordinates, kept until the next sweep.
    """

    estimator: EstimatorState
    pid: PidState
    avoidance_offset_m: FloatArray
    echo_points_m: FloatArray
    echo_valid: BoolArray

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
    trajectory at t_s (used by the leader only).
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


def sonar_beam_points(
    pose: FloatArray, sonar_range_m: FloatArray, params: ControllerParams
) -> FloatArray:
    """World points (..., S, 2) at ``sonar_range_m`` (finite, from the body's rim) along each
    transducer's beam of a robot at ``pose`` (..., 3): where its sonar ring says echoes are."""
    beam_world = pose[..., 2:3] + np.asarray(params.sonar_beam_angles_rad)
    reach = params.body_radius_m + sonar_range_m
    return np.stack(
        (
            pose[..., None, 0] + reach * np.cos(beam_world),
            pose[..., None, 1] + reach * np.sin(beam_world),
        ),
        axis=-1,
    )


def sonar_echo_points(
    pose: FloatArray,
    sonar_range_m: FloatArray,
    peer_pose: FloatArray,
    peer_ok: BoolArray,
    params: ControllerParams,
) -> tuple[FloatArray, BoolArray]:
    """Level 2: a sonar sweep as obstacle points in the world (..., S, 2) and their validity.

    Echoes within the APF influence distance count; an echo that lands on a peer whose position
    is known from the radio is left to the robot-robot term.
    """
    echo = np.isfinite(sonar_range_m) & (sonar_range_m <= params.apf_influence_m)
    points = sonar_beam_points(pose, np.where(echo, sonar_range_m, 0.0), params)
    to_peer = points[..., :, None, :] - peer_pose[..., None, :, :2]
    near_peer = np.hypot(to_peer[..., 0], to_peer[..., 1]) < (
        params.body_radius_m + params.sonar_peer_margin_m
    )
    explained = np.any(near_peer & peer_ok[..., None, :], axis=-1)
    return points, echo & ~explained


def control_step(
    state: ControllerState,
    inputs: ControlInputs,
    role: RobotRole,
    rule_base: FuzzyRuleBase,
    params: ControllerParams,
) -> tuple[ControllerState, ControlOutputs]:
    """Advance one control period; returns the new state and the wheel commands."""
    dt = params.control_period_s
    est = odometry_update(
        state.estimator,
        inputs.encoder_counts,
        dt,
        params.encoder_counts_per_rev,
        params.wheel_radius_m,
        params.wheel_base_m,
        params.rate_filter_time_constant_s,
    )
    est = fuse_pose_fix(est, inputs.fix_pose, inputs.fix_valid, params.fix_gain)
    pose = est.pose
    theta = pose[..., 2]

    # Level 3: peers and the desired pose.
    age_s = inputs.t_s - inputs.peer_stamp_s
    peer_ok = inputs.peer_valid & (age_s <= params.peer_timeout_s)
    lead_time_s = np.where(peer_ok, np.maximum(age_s, 0.0), 0.0)
    peer_pose = inputs.peer_pose + inputs.peer_rate * lead_time_s[..., None]
    leader_mask = peer_ok & inputs.peer_is_leader
    leader_known = np.any(leader_mask, axis=-1)
    first_leader = (leader_mask & (np.cumsum(leader_mask, axis=-1) == 1))[..., None]
    leader_pose = np.sum(np.where(first_leader, peer_pose, 0.0), axis=-2)
    leader_rate = np.sum(np.where(first_leader, inputs.peer_rate, 0.0), axis=-2)
    slot_pose, slot_rate = follower_reference(
        leader_pose, leader_rate, pose, role.slot_distance_m, role.slot_angle_rad
    )
    lead = role.is_leader[..., None]
    desired_pose = np.where(lead, inputs.reference_pose, slot_pose)
    desired_rate = np.where(lead, inputs.reference_rate, slot_rate)

    # Level 3: APF from peers (radio) and from sonar echoes not explained by a peer.
    to_self = pose[..., None, :2] - peer_pose[..., :2]
    centre_gap = np.hypot(to_self[..., 0], to_self[..., 1])
    peer_dir = to_self / np.maximum(centre_gap, 1e-9)[..., None]
    peer_gap = centre_gap - 2.0 * params.body_radius_m
    force = repulsive_force(
        peer_dir,
        peer_gap,
        peer_ok,
        params.apf_robot_gain,
        params.apf_influence_m,
        params.apf_min_gap_m,
    )
    if inputs.sonar_fresh:
        echo_points, echo_valid = sonar_echo_points(
            pose, inputs.sonar_range_m, peer_pose, peer_ok, params
        )
    else:
        echo_points, echo_valid = state.echo_points_m, state.echo_valid
    from_echo = pose[..., None, :2] - echo_points
    echo_distance = np.hypot(from_echo[..., 0], from_echo[..., 1])
    force = force + repulsive_force(
        from_echo / np.maximum(echo_distance, 1e-9)[..., None],
        echo_distance - params.body_radius_m,
        echo_valid,
        params.apf_obstacle_gain,
        params.apf_influence_m,
        params.apf_min_gap_m,
    )
    repulsion = clip_norm(force, params.apf_max_speed_mps)
    avoiding = np.any(repulsion != 0.0, axis=-1)
    leak_time_constant_s = np.where(
        avoiding, params.avoidance_hold_time_constant_s, params.avoidance_release_time_constant_s
    )
    offset_rate = repulsion - state.avoidance_offset_m / leak_time_constant_s[..., None]
    offset = state.avoidance_offset_m + offset_rate * dt
    desired_pose = desired_pose.copy()
    desired_rate = desired_rate.copy()
    desired_pose[..., :2] += offset
    desired_rate[..., :2] += offset_rate

    # Level 4: fuzzy-scheduled gains and the redundant PID law.
    error = tracking_error(pose, desired_pose)
    error_rate = filtered_error_rate(state.pid, error, dt, params.derivative_filter_time_constant_s)
    if params.fuzzy_enabled:
        delta_k = infer(
            rule_base,
            error / np.asarray(params.error_scale),
            error_rate / np.asarray(params.error_rate_scale),
        )
    else:
        delta_k = np.zeros_like(error)
    kp, ki, kd = params.gains(delta_k)
    active = est.localised & (role.is_leader | leader_known)
    pid, wheel = redundant_pid_law(
        state.pid,
        error,
        error_rate,
        desired_rate,
        theta,
        kp,
        ki,
        kd,
        active & ~avoiding,
        dt,
        np.asarray(params.integral_limit),
        params.wheel_base_m,
        params.wheel_radius_m,
        params.max_wheel_speed_radps,
    )
    wheel = np.where(active[..., None], wheel, 0.0)
    duty = np.clip(wheel / params.motor_no_load_speed_radps, -1.0, 1.0)
    new_state = ControllerState(
        estimator=est,
        pid=pid,
        avoidance_offset_m=offset,
        echo_points_m=echo_points,
        echo_valid=echo_valid,
    )
    outputs = ControlOutputs(
        wheel_speed_radps=wheel,
        duty=duty,
        desired_pose=desired_pose,
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

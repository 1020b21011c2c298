"""The control step and the body step written out in numpy: the specification the compiled
kernels are tested against (tests/control/test_kernels_match_oracle.py).

This is the array form the project ran before the kernels (robot_firmware/control/*.py and
world/physics.py), kept here as a readable statement of the math and nowhere else: nothing in
the packages imports it.  Every function takes arrays with arbitrary leading batch axes.

    kinematics        eqs. 9-11 (element-wise forms of P(θ) and P#(θ), DESIGN.md §6)
    PID law           eqs. 12 and 14 with anti-windup and wheel-speed saturation
    estimator         odometry through eq. 11 at the mid-step heading, fix fusion
    formation         eqs. 17-21 (atan2 form of eq. 20)
    APF               eq. 25 per pair, floored gap, clipped total; the tangential part round
                      other robots and the desired point kept clear of them
    approach guard    the commanded velocity's approach to every known body bounded by the
                      gap left (apf.py, `limit_approach`)
    fuzzy scheduler   eqs. 6-7 with Table 2: the four firing rules, and the full product
    control_step      one tick of 5C levels 2-4 (robot_firmware/control/controller.py)
    step_bodies       first-order motors, exact θ(t), 3-point Gauss-Legendre position
    resolve_contacts  circle-circle push-apart
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    ControlOutputs,
    RobotRole,
)
from robot_firmware.control.estimation import EstimatorState
from robot_firmware.control.fuzzy import MAX_SETS, FuzzyRuleBase
from robot_firmware.control.kinematics import WHEEL_ANGLE_OFFSET_RAD
from robot_firmware.control.pid import PidState
from swarm_config.body import BodyParams
from world.physics import BodyState, ContactReport

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

_GAUSS_NODES = 0.5 * (1.0 + np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)]))
_GAUSS_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0


def gains(
    params: ControllerParams, delta_k: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """K_P, K_I, K_D (..., 3) for a fuzzy output ΔK (..., 3): K = K₀·(1 + η·ΔK)."""
    fp, fi, fd = params.fuzzy_gain_fraction
    kp = np.asarray(params.kp)
    ki = np.asarray(params.ki)
    kd = np.asarray(params.kd)
    return kp * (1.0 + fp * delta_k), ki * (1.0 + fi * delta_k), kd * (1.0 + fd * delta_k)


def wrap_angle_rad(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles to (-π, π]."""
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return np.asarray(wrapped, dtype=np.float64)


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


def tracking_error(pose: FloatArray, desired_pose: FloatArray) -> FloatArray:
    """Eq. 12, Y_e = Y - Y_d, with the heading component wrapped to (-π, π]."""
    e = pose - desired_pose
    e[..., 2] = wrap_angle_rad(e[..., 2])
    return e


def filtered_error_rate(
    state: PidState, error: FloatArray, dt_s: float, filter_time_constant_s: float
) -> FloatArray:
    """ė as a first-order low-pass of the backward difference (zero on the first tick)."""
    raw = (error - state.previous_error) / dt_s
    raw[..., 2] = wrap_angle_rad(error[..., 2] - state.previous_error[..., 2]) / dt_s
    alpha = filter_time_constant_s / (filter_time_constant_s + dt_s)
    rate = alpha * state.error_rate + (1.0 - alpha) * raw
    return np.where(state.started[..., None], rate, 0.0)


def redundant_pid_law(
    state: PidState,
    error: FloatArray,
    error_rate: FloatArray,
    desired_rate: FloatArray,
    theta_rad: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    kd: FloatArray,
    integrate: BoolArray,
    dt_s: float,
    integral_limit: FloatArray,
    wheel_base_m: float,
    wheel_radius_m: float,
    max_wheel_speed_radps: float,
) -> tuple[PidState, FloatArray]:
    """One tick of eq. 14: returns the new state and the wheel speed command (..., 4) in rad/s."""
    hold = state.saturated | ~integrate
    integral = np.where(hold[..., None], state.integral, state.integral + error * dt_s)
    integral = np.clip(integral, -integral_limit, integral_limit)
    command = desired_rate - kp * error - ki * integral - kd * error_rate
    wheel_radps = wheel_speeds_from_pose_rate(command, theta_rad, wheel_base_m) / wheel_radius_m
    peak = np.max(np.abs(wheel_radps), axis=-1)
    scale = np.maximum(peak / max_wheel_speed_radps, 1.0)
    wheel_radps = wheel_radps / scale[..., None]
    new_state = PidState(
        integral=integral,
        previous_error=error,
        error_rate=error_rate,
        saturated=scale > 1.0,
        started=np.ones_like(state.started),
    )
    return new_state, wheel_radps


def odometry_update(
    state: EstimatorState,
    encoder_counts: IntArray,
    dt_s: float,
    counts_per_rev: int,
    wheel_radius_m: float,
    wheel_base_m: float,
    rate_filter_time_constant_s: float,
) -> EstimatorState:
    """Advance the estimate by the wheel travel measured since the previous tick (eq. 11)."""
    delta_counts = encoder_counts - state.previous_counts
    metres_per_count = 2.0 * np.pi * wheel_radius_m / counts_per_rev
    travel_m = delta_counts.astype(np.float64) * metres_per_count
    # Evaluate P# at the mid-step heading for second-order accuracy on turning robots.
    first = pose_rate_from_wheel_speeds(travel_m, state.pose[..., 2], wheel_base_m)
    mid_theta = state.pose[..., 2] + 0.5 * first[..., 2]
    step = pose_rate_from_wheel_speeds(travel_m, mid_theta, wheel_base_m)
    pose = state.pose + step
    pose[..., 2] = wrap_angle_rad(pose[..., 2])
    alpha = rate_filter_time_constant_s / (rate_filter_time_constant_s + dt_s)
    rate = alpha * state.rate + (1.0 - alpha) * (step / dt_s)
    return EstimatorState(
        pose=pose, rate=rate, previous_counts=encoder_counts, localised=state.localised
    )


def fuse_pose_fix(
    state: EstimatorState, fix_pose: FloatArray, fix_valid: BoolArray, fix_gain: float
) -> EstimatorState:
    """Blend a new pose fix into the estimate; the first fix after boot is taken whole."""
    gain = np.where(state.localised, fix_gain, 1.0)
    gain = np.where(fix_valid, gain, 0.0)[..., None]
    innovation = fix_pose - state.pose
    innovation[..., 2] = wrap_angle_rad(innovation[..., 2])
    pose = state.pose + gain * innovation
    pose[..., 2] = wrap_angle_rad(pose[..., 2])
    return EstimatorState(
        pose=pose,
        rate=state.rate,
        previous_counts=state.previous_counts,
        localised=state.localised | fix_valid,
    )


def slot_in_leader_frame(
    distance_m: FloatArray | float, angle_rad: FloatArray | float
) -> tuple[FloatArray, FloatArray]:
    """Eq. 17."""
    d = np.asarray(distance_m, dtype=np.float64)
    a = np.asarray(angle_rad, dtype=np.float64)
    return d * np.cos(a), d * np.sin(a)


def follower_slot_in_follower_frame(
    leader_pose: FloatArray,
    follower_pose: FloatArray,
    distance_m: FloatArray | float,
    angle_rad: FloatArray | float,
) -> FloatArray:
    """Eqs. 17-21: the follower's desired position expressed in its own frame, shape (..., 2)."""
    x_dl, y_dl = slot_in_leader_frame(distance_m, angle_rad)  # eq. 17
    dx = leader_pose[..., 0] - follower_pose[..., 0]
    dy = leader_pose[..., 1] - follower_pose[..., 1]
    theta_fo = follower_pose[..., 2]
    theta_lo = leader_pose[..., 2]
    theta_mf = np.arctan2(dy, dx)  # eq. 20, corrected
    theta_ml = np.arctan2(-dy, -dx)
    theta_lf = wrap_angle_rad(theta_mf - theta_fo)
    theta_fl = wrap_angle_rad(theta_ml - theta_lo)
    phi = wrap_angle_rad(np.pi - theta_lf + theta_fl)  # eq. 21
    l_lf = np.hypot(dx, dy)
    x_lf = l_lf * np.cos(theta_lf)  # eq. 18
    y_lf = l_lf * np.sin(theta_lf)
    cp = np.cos(phi)
    sp = np.sin(phi)
    x_df = x_dl * cp + y_dl * sp + x_lf  # eq. 19
    y_df = -x_dl * sp + y_dl * cp + y_lf
    return np.stack((x_df, y_df), axis=-1)


def follower_frame_to_world(point_in_follower: FloatArray, follower_pose: FloatArray) -> FloatArray:
    """Rotate and translate a point from the follower's frame to world coordinates."""
    c = np.cos(follower_pose[..., 2])
    s = np.sin(follower_pose[..., 2])
    x = follower_pose[..., 0] + c * point_in_follower[..., 0] - s * point_in_follower[..., 1]
    y = follower_pose[..., 1] + s * point_in_follower[..., 0] + c * point_in_follower[..., 1]
    return np.stack((x, y), axis=-1)


def follower_slot_in_world(
    leader_pose: FloatArray, distance_m: FloatArray | float, angle_rad: FloatArray | float
) -> FloatArray:
    """The slot of eq. 17 placed in world coordinates from the leader's pose, shape (..., 2)."""
    x_dl, y_dl = slot_in_leader_frame(distance_m, angle_rad)
    c = np.cos(leader_pose[..., 2])
    s = np.sin(leader_pose[..., 2])
    return np.stack(
        (leader_pose[..., 0] + c * x_dl - s * y_dl, leader_pose[..., 1] + s * x_dl + c * y_dl),
        axis=-1,
    )


def follower_reference(
    leader_pose: FloatArray,
    leader_rate: FloatArray,
    follower_pose: FloatArray,
    distance_m: FloatArray | float,
    angle_rad: FloatArray | float,
) -> tuple[FloatArray, FloatArray]:
    """Desired pose (..., 3) and pose rate (..., 3) of a follower in world coordinates.

    The position comes from eqs. 17-21 in the follower's frame, mapped back to the world; the
    heading is the leader's, wrapped to (-π, π] (a peer's heading extrapolated by its rate can
    pass ±π).  The rate is the slot's velocity when the leader moves with
    `leader_rate`: ṗ_L + θ̇_L × R(θ_L)·(x_DL, y_DL).
    """
    slot_f = follower_slot_in_follower_frame(leader_pose, follower_pose, distance_m, angle_rad)
    slot_w = follower_frame_to_world(slot_f, follower_pose)
    desired = np.concatenate((slot_w, wrap_angle_rad(leader_pose[..., 2:3])), axis=-1)
    arm_x = slot_w[..., 0] - leader_pose[..., 0]
    arm_y = slot_w[..., 1] - leader_pose[..., 1]
    spin = leader_rate[..., 2]
    rate = np.stack(
        (leader_rate[..., 0] - spin * arm_y, leader_rate[..., 1] + spin * arm_x, spin), axis=-1
    )
    return desired, rate


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
    magnitude = pair_magnitude(gap_m, valid, gain, influence_m, min_gap_m)
    return np.asarray(np.sum(magnitude[..., None] * direction_from_source, axis=-2))


def pair_magnitude(
    gap_m: FloatArray, valid: BoolArray, gain: float, influence_m: float, min_gap_m: float
) -> FloatArray:
    """Eq. 25 for each pair (..., K): the magnitude along the source-to-robot direction."""
    rho = np.maximum(gap_m, min_gap_m)
    magnitude = gain * (1.0 / rho - 1.0 / influence_m) / (rho * rho)
    return np.where(valid & (gap_m <= influence_m), magnitude, 0.0)


def clip_norm(vector: FloatArray, max_norm: float) -> FloatArray:
    """Scale vectors (..., 2) down to at most `max_norm`, keeping their direction."""
    norm = np.hypot(vector[..., 0], vector[..., 1])
    scale = np.minimum(1.0, max_norm / np.maximum(norm, 1e-12))
    return vector * scale[..., None]


@dataclass(frozen=True)
class _CentreLookup:
    """Centres of a batch of schedulers laid end to end for one `searchsorted`.

    Scheduler r's centres are shifted by r·spread so that the concatenation is sorted; padding
    repeats the last centre.  Inputs are clipped to their own scheduler's [first, last].
    """

    keys: FloatArray
    values: FloatArray
    shift: FloatArray
    key_base: IntArray
    last_pair: IntArray
    first: FloatArray
    below_last: FloatArray


def _centre_lookup(centres: FloatArray, set_count: IntArray) -> _CentreLookup:
    batch_shape = centres.shape[:-1]
    count = np.broadcast_to(set_count, batch_shape)
    last = np.take_along_axis(centres, (count - 1)[..., None], axis=-1)[..., 0]
    padded = np.where(np.isfinite(centres), centres, last[..., None])
    spread = float(np.max(padded) - np.min(padded)) + 1.0
    index = np.arange(int(np.prod(batch_shape, dtype=np.int64))).reshape(batch_shape)
    shift = index * spread
    return _CentreLookup(
        keys=(padded + shift[..., None]).reshape(-1),
        values=padded.reshape(-1).astype(np.float64),
        shift=np.asarray(shift, dtype=np.float64),
        key_base=np.asarray(index * MAX_SETS, dtype=np.int64),
        last_pair=np.asarray(index * MAX_SETS + count - 2, dtype=np.int64),
        first=np.asarray(padded[..., 0], dtype=np.float64),
        below_last=np.nextafter(last, -np.inf),
    )


def _active_pair(x: FloatArray, lookup: _CentreLookup) -> tuple[IntArray, FloatArray]:
    """Index k of the left active set and the membership of set k+1 (set k has 1 - that)."""
    xc = np.minimum(np.maximum(x, lookup.first), lookup.below_last)
    query = xc + lookup.shift
    g = np.searchsorted(lookup.keys, query, side="right") - 1
    # The shift can round a query onto a neighbouring key; keep it inside its own scheduler.
    g = np.minimum(np.maximum(g, lookup.key_base), lookup.last_pair)
    # Memberships from the unshifted centres, so a scheduler's output does not depend on where
    # it sits in the batch.
    ck = lookup.values[g]
    ck1 = lookup.values[g + 1]
    mu_right = np.minimum(np.maximum((xc - ck) / (ck1 - ck), 0.0), 1.0)
    return np.asarray(g - lookup.key_base, dtype=np.int64), mu_right


def infer(rule_base: FuzzyRuleBase, error_norm: FloatArray, rate_norm: FloatArray) -> FloatArray:
    """ΔK for normalised inputs (eqs. 6-7), gathering only the four rules that fire."""
    ke, me = _active_pair(
        error_norm, _centre_lookup(rule_base.error_centres, rule_base.error_set_count)
    )
    kd, md = _active_pair(
        rate_norm, _centre_lookup(rule_base.rate_centres, rule_base.rate_set_count)
    )
    flat = np.ascontiguousarray(rule_base.rule_outputs).reshape(-1)
    batch_shape = rule_base.rule_outputs.shape[:-2]
    count = int(np.prod(batch_shape, dtype=np.int64))
    table_base = np.arange(count, dtype=np.int64).reshape(batch_shape) * MAX_SETS**2
    base = table_base + ke * MAX_SETS + kd
    le = 1.0 - me
    ld = 1.0 - md
    # The four activations sum to one (half overlap), so eq. 6's denominator is 1.
    return np.asarray(
        le * (ld * flat[base] + md * flat[base + 1])
        + me * (ld * flat[base + MAX_SETS] + md * flat[base + MAX_SETS + 1]),
        dtype=np.float64,
    )


def memberships(x: ArrayLike, centres: ArrayLike) -> FloatArray:
    """Membership of x in every set of one input (unpadded centres), shape x.shape + (n,)."""
    c = np.asarray(centres, dtype=np.float64)
    xv = np.clip(np.asarray(x, dtype=np.float64), c[0], c[-1])[..., None]
    left = np.concatenate([[c[0] - 1.0], c[:-1]])
    right = np.concatenate([c[1:], [c[-1] + 1.0]])
    rising = (xv - left) / (c - left)
    falling = (right - xv) / (right - c)
    mu = np.clip(np.minimum(rising, falling), 0.0, 1.0)
    mu[..., 0] = np.where(xv[..., 0] <= c[0], 1.0, mu[..., 0])
    mu[..., -1] = np.where(xv[..., 0] >= c[-1], 1.0, mu[..., -1])
    return np.asarray(mu, dtype=np.float64)


def infer_full_product(
    error_centres: ArrayLike,
    rate_centres: ArrayLike,
    rule_outputs: ArrayLike,
    error_norm: ArrayLike,
    rate_norm: ArrayLike,
) -> FloatArray:
    """Eqs. 6-7 written out over all K rules, for one scheduler (unpadded arrays)."""
    mu_e = memberships(error_norm, error_centres)
    mu_d = memberships(rate_norm, rate_centres)
    activation = mu_e[..., :, None] * mu_d[..., None, :]  # eq. 7, every rule
    rules = np.asarray(rule_outputs, dtype=np.float64)
    num = np.sum(activation * rules, axis=(-2, -1))
    den = np.sum(activation, axis=(-2, -1))
    return np.asarray(num / den, dtype=np.float64)  # eq. 6


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
    peer_magnitude = pair_magnitude(
        peer_gap, peer_ok, params.apf_robot_gain, params.apf_influence_m, params.apf_min_gap_m
    )
    force = np.sum(peer_magnitude[..., None] * peer_dir, axis=-2)
    stopped = (
        np.zeros(peer_ok.shape, dtype=bool)
        if inputs.peer_stopped is None
        else np.broadcast_to(inputs.peer_stopped, peer_ok.shape)
    )
    if inputs.sonar_fresh:
        # Echoes on a stopped peer stay: its pose is only where it was last heard to coast to.
        echo_points, echo_valid = sonar_echo_points(
            pose, inputs.sonar_range_m, peer_pose, peer_ok & ~stopped, params
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

    # Level 3: the tangential part round every robot that repels: round a stopped one to the
    # side chosen when it began to repel (the goal and the other sources' push), kept while
    # it repels; round a live one anticlockwise.
    prior_side = (
        np.zeros(peer_ok.shape)
        if state.circulation_side is None
        else np.broadcast_to(state.circulation_side, peer_ok.shape)
    )
    goal = desired_rate[..., :2] + (desired_pose[..., :2] - pose[..., :2]) / (
        params.avoidance_hold_time_constant_s
    )
    tangent = np.stack((-peer_dir[..., 1], peer_dir[..., 0]), axis=-1)
    lean = goal[..., None, :] + force[..., None, :] - peer_magnitude[..., None] * peer_dir
    leaning = np.where(np.sum(tangent * lean, axis=-1) >= 0.0, 1.0, -1.0)
    stopped_side = np.where(prior_side != 0.0, prior_side, leaning)
    repels = peer_magnitude != 0.0
    circulation_side = np.where(repels & stopped, stopped_side, 0.0)
    side = np.where(stopped, stopped_side, 1.0)
    turn_magnitude = np.where(repels, side * params.apf_circulation_ratio * peer_magnitude, 0.0)
    turn = np.sum(turn_magnitude[..., None] * tangent, axis=-2)
    repulsion = clip_norm(force, params.apf_max_speed_mps) + clip_norm(
        turn, params.apf_circulation_ratio * params.apf_max_speed_mps
    )
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

    # Level 3: the desired point kept clear of every robot that repels, one after the other:
    # at least two body radii plus the clearance from it along the line through the robot, and
    # without a velocity back towards it.
    near = peer_ok & (peer_gap <= params.apf_influence_m)
    reach_m = 2.0 * params.body_radius_m + params.apf_clearance_m
    for j in range(peer_ok.shape[-1]):
        direction = peer_dir[..., j, :]
        along_m = np.sum((desired_pose[..., :2] - peer_pose[..., j, :2]) * direction, axis=-1)
        push_m = np.where(near[..., j], np.maximum(reach_m - along_m, 0.0), 0.0)
        inward_mps = np.where(
            near[..., j], np.minimum(np.sum(desired_rate[..., :2] * direction, axis=-1), 0.0), 0.0
        )
        offset = offset + push_m[..., None] * direction
        desired_pose[..., :2] += push_m[..., None] * direction
        desired_rate[..., :2] -= inward_mps[..., None] * direction

    # Level 4: fuzzy-scheduled gains and the redundant PID law.
    error = tracking_error(pose, desired_pose)
    error_rate = filtered_error_rate(state.pid, error, dt, params.derivative_filter_time_constant_s)
    if params.fuzzy_enabled:
        delta_k = infer(
            rule_base.expand_dims((0,)),  # one scheduler for the three axes
            error / np.asarray(params.error_scale),
            error_rate / np.asarray(params.error_rate_scale),
        )
    else:
        delta_k = np.zeros_like(error)
    kp, ki, kd = gains(params, delta_k)
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
    if params.approach_guard:
        wheel, guarded = approach_guard(
            wheel,
            pose,
            peer_pose,
            inputs.peer_rate,
            peer_ok,
            stopped,
            echo_points,
            echo_valid,
            active,
            params,
        )
        pid = replace(pid, saturated=pid.saturated | guarded)
    wheel = np.where(active[..., None], wheel, 0.0)
    duty = np.clip(wheel / params.motor_no_load_speed_radps, -1.0, 1.0)
    new_state = ControllerState(
        estimator=est,
        pid=pid,
        avoidance_offset_m=offset,
        echo_points_m=echo_points,
        echo_valid=echo_valid,
        circulation_side=circulation_side,
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


def approach_guard(
    wheel_radps: FloatArray,
    pose: FloatArray,
    peer_pose: FloatArray,
    peer_rate: FloatArray,
    peer_ok: BoolArray,
    peer_stopped: BoolArray,
    echo_points: FloatArray,
    echo_valid: BoolArray,
    active: BoolArray,
    params: ControllerParams,
) -> tuple[FloatArray, BoolArray]:
    """The commanded wheel speeds with the approach to every peer (radio) and every sonar echo
    cut to min(share · budget, budget - the peer's own approach), budget = (gap - guard gap) /
    guard time constant (a live peer's share 0.5, a stopped peer's and an echo's 1; a stopped
    peer's velocity and an echo's are 0), the bounds applied one after the other, twice over,
    then the wheel speeds scaled back under their limit; and where that changed the command."""
    r, L = params.wheel_radius_m, params.wheel_base_m
    theta = pose[..., 2]
    rate = pose_rate_from_wheel_speeds(wheel_radps * r, theta, L)
    velocity = rate[..., :2].copy()
    guarded = np.zeros(theta.shape, dtype=bool)
    to_peer = pose[..., None, :2] - peer_pose[..., :2]
    peer_centre_gap = np.hypot(to_peer[..., 0], to_peer[..., 1])
    peer_dir = to_peer / np.maximum(peer_centre_gap, 1e-9)[..., None]
    peer_gap = peer_centre_gap - 2.0 * params.body_radius_m
    peer_share = np.where(peer_stopped, 1.0, 0.5)
    to_echo = pose[..., None, :2] - echo_points
    echo_distance = np.hypot(to_echo[..., 0], to_echo[..., 1])
    echo_dir = to_echo / np.maximum(echo_distance, 1e-9)[..., None]
    echo_gap = echo_distance - params.body_radius_m

    peer_approach = np.sum(peer_rate[..., :2] * peer_dir, axis=-1)

    def bound(
        direction: FloatArray,
        gap: FloatArray,
        share: FloatArray,
        other_approach: FloatArray,
        valid: BoolArray,
    ) -> None:
        budget = (gap - params.guard_gap_m) / params.guard_time_constant_s
        allowed = np.minimum(share * budget, budget - other_approach)
        approach = -np.sum(velocity * direction, axis=-1)
        cut = valid & active & (approach > allowed)
        velocity[...] += np.where(cut, approach - allowed, 0.0)[..., None] * direction
        guarded[...] |= cut

    for _ in range(2):
        for j in range(peer_ok.shape[-1]):
            bound(
                peer_dir[..., j, :],
                peer_gap[..., j],
                peer_share[..., j],
                peer_approach[..., j],
                peer_ok[..., j],
            )
        for k in range(echo_valid.shape[-1]):
            one = np.ones(echo_gap[..., k].shape)
            bound(echo_dir[..., k, :], echo_gap[..., k], one, 0.0 * one, echo_valid[..., k])
    command = np.concatenate((velocity, rate[..., 2:]), axis=-1)
    guarded_radps = wheel_speeds_from_pose_rate(command, theta, L) / r
    peak = np.max(np.abs(guarded_radps), axis=-1)
    guarded_radps = guarded_radps / np.maximum(peak / params.max_wheel_speed_radps, 1.0)[..., None]
    return np.where(guarded[..., None], guarded_radps, wheel_radps), guarded


def step_bodies(
    state: BodyState,
    duty: FloatArray,
    dt_s: float,
    slip_noise: FloatArray,
    params: BodyParams,
) -> BodyState:
    """Advance the bodies by dt_s with the duty held constant.

    slip_noise: standard normal draws (..., 4) for the slip process (pass zeros for no slip).
    """
    tau = params.motor_time_constant_s
    target = np.clip(duty, -1.0, 1.0) * params.motor_no_load_speed_radps
    decay = np.exp(-dt_s / tau)
    transient = state.wheel_speed_radps - target
    wheel_end = target + transient * decay
    wheel_angle = state.wheel_angle_rad + target * dt_s + transient * (tau * (1.0 - decay))

    # Rim ground speeds v(t) = r(1+s)·(target + transient·e^(-t/τ)), split into the constant and
    # the decaying part of the three body-rate components of eq. 11.
    gain = params.wheel_radius_m * (1.0 + state.slip)
    steady = gain * target
    fading = gain * transient
    L4 = 4.0 * params.wheel_base_m

    def split(v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        a = 0.5 * (v[..., 2] - v[..., 0])
        b = 0.5 * (v[..., 3] - v[..., 1])
        w = (v[..., 0] + v[..., 1] + v[..., 2] + v[..., 3]) / L4
        return a, b, w

    a_ss, b_ss, w_ss = split(steady)
    a_tr, b_tr, w_tr = split(fading)
    t = dt_s * _GAUSS_NODES  # (3,)
    e_t = np.exp(-t / tau)
    theta0 = state.pose[..., 2:3]
    theta_t = theta0 + w_ss[..., None] * t + w_tr[..., None] * (tau * (1.0 - e_t))
    a_t = a_ss[..., None] + a_tr[..., None] * e_t
    b_t = b_ss[..., None] + b_tr[..., None] * e_t
    phi = theta_t + WHEEL_ANGLE_OFFSET_RAD
    s = np.sin(phi)
    c = np.cos(phi)
    weights = dt_s * _GAUSS_WEIGHTS
    dx = np.sum(weights * (s * a_t + c * b_t), axis=-1)
    dy = np.sum(weights * (-c * a_t + s * b_t), axis=-1)
    dtheta = w_ss * dt_s + w_tr * (tau * (1.0 - decay))
    pose = np.stack(
        (
            state.pose[..., 0] + dx,
            state.pose[..., 1] + dy,
            wrap_angle_rad(state.pose[..., 2] + dtheta),
        ),
        axis=-1,
    )
    rho = np.exp(-dt_s / params.slip_correlation_time_s)
    slip = rho * state.slip + params.slip_std * np.sqrt(1.0 - rho * rho) * slip_noise
    return BodyState(pose=pose, wheel_speed_radps=wheel_end, wheel_angle_rad=wheel_angle, slip=slip)


def encoder_counts(wheel_angle_rad: FloatArray, counts_per_rev: int) -> IntArray:
    """Quadrature encoder position after 4x decoding: the angle quantised to whole counts."""
    return np.floor(wheel_angle_rad * (counts_per_rev / (2.0 * np.pi))).astype(np.int64)


def resolve_contacts(
    positions_m: FloatArray,
    body_radius_m: float,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
) -> tuple[FloatArray, ContactReport]:
    """Push overlapping bodies apart; positions (..., N, 2), obstacles (M, 2) and (M,).

    Returns the corrected positions and which pairs were in contact before correction.
    """
    n = positions_m.shape[-2]
    delta = positions_m[..., :, None, :] - positions_m[..., None, :, :]
    dist = np.hypot(delta[..., 0], delta[..., 1])
    overlap_rr = 2.0 * body_radius_m - dist
    not_self = ~np.eye(n, dtype=bool)
    touching_rr = (overlap_rr > 0.0) & not_self
    away = delta / np.maximum(dist, 1e-9)[..., None]
    push_rr = np.where(touching_rr, 0.5 * overlap_rr, 0.0)[..., None] * away
    corrected = positions_m + np.sum(push_rr, axis=-2)

    to_body = corrected[..., :, None, :] - obstacle_centres_m
    dist_o = np.hypot(to_body[..., 0], to_body[..., 1])
    overlap_o = body_radius_m + obstacle_radii_m - dist_o
    touching_o = overlap_o > 0.0
    away_o = to_body / np.maximum(dist_o, 1e-9)[..., None]
    push_o = np.where(touching_o, overlap_o, 0.0)[..., None] * away_o
    corrected = corrected + np.sum(push_o, axis=-2)
    return corrected, ContactReport(robot_robot=touching_rr, robot_obstacle=touching_o)

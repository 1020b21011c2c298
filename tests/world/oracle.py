"""The world's step, its metrics and the batch simulator's tick loop written out in numpy: the
specification the compiled kernels are tested against (tests/world/test_kernels_match_oracle.py)
and the numpy path bench/batch_throughput.py times next to the compiled one.

This is the array form the project ran before the world's kernels and the compiled tick loop
(world/sensors.py, world/radio.py, world/metrics.py, world/step.py, services/sim/batch.py and
services/sim/ticks.py), kept here as a readable statement and nowhere else: nothing in the
packages imports it.  The control step and the body step are tests/control/oracle.py's.

    sonar_gaps, pose_fix   the sonar ring and the positioning fix (DESIGN.md §4)
    draw_links             per-frame loss and delay, Gilbert-Elliott bursts, range, cuts
    sense_world, broadcast, step_world
                           one world step batched over runs and robots (world/step.py)
    MetricsOracle          `MetricsAccumulator` with its sample update in numpy
    BatchRadio             the frames in flight, per sender a ring of slots
    run_batch_oracle       the batch simulator tick by tick
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    RobotRole,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.sim.batch import BatchResult, Trace
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario, load_rule_base
from swarm_config.sensors import PositioningParams, SonarParams
from tests.control.oracle import control_step, encoder_counts, resolve_contacts, step_bodies
from world.metrics import (
    FormationLayout,
    MetricsAccumulator,
    obstacle_gaps,
    reference_points,
    robot_gaps,
    sample_errors,
)
from world.radio import LinkDraw, LinkTable
from world.step import (
    FrameFates,
    Observation,
    WorldInputs,
    WorldNoise,
    WorldParams,
    WorldState,
    sonar_targets,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


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


def draw_links(
    links: LinkProfile | LinkTable,
    in_bad_state: BoolArray,
    link_length_m: FloatArray | None,
    rng: np.random.Generator,
) -> LinkDraw:
    """Fate of one frame on each link of shape `in_bad_state.shape` (a table's fields broadcast
    against it)."""
    table = LinkTable.from_profile(links) if isinstance(links, LinkProfile) else links
    shape = in_bad_state.shape
    u_loss = rng.random(shape)
    u_delay = rng.random(shape)
    if not np.any(table.burst):
        lost = u_loss < table.loss
        bad = in_bad_state
    else:
        u_state = rng.random(shape)
        flipped = np.where(in_bad_state, u_state >= table.bad_to_good, u_state < table.good_to_bad)
        bad = np.where(table.burst, flipped, in_bad_state)
        in_burst = np.where(bad, table.loss_in_bad, table.loss_in_good)
        lost = u_loss < np.where(table.burst, in_burst, table.loss)
    if table.range_m is not None and link_length_m is not None:
        lost = lost | (link_length_m > table.range_m)
    if np.any(table.cut):
        lost = lost | table.cut
    delay_ms = table.latency_ms + table.jitter_ms * (2.0 * u_delay - 1.0)
    return LinkDraw(delivered=~lost, delay_s=np.maximum(delay_ms, 0.0) / 1000.0, in_bad_state=bad)


def sense_world(
    state: WorldState,
    params: WorldParams,
    noise: WorldNoise,
    fix_due: bool,
    sonar_due: bool,
) -> Observation:
    """Encoders always; a positioning fix and a sonar sweep when due (draws only then)."""
    bodies = state.bodies
    n = state.robot_count
    counts = encoder_counts(bodies.wheel_angle_rad, params.body.encoder_counts_per_rev)
    fix = None
    if fix_due:
        fix = pose_fix(
            bodies.pose, noise.fix.standard_normal(noise.batch_shape + (n, 3)), params.positioning
        )
    gaps = None
    if sonar_due:
        centres, radii, valid = sonar_targets(bodies.pose[..., :2], params)
        beams = params.beam_angles_rad
        gaps = sonar_gaps(
            bodies.pose,
            beams,
            centres,
            radii,
            valid,
            params.body.body_radius_m,
            noise.sonar.standard_normal(noise.batch_shape + (n, len(beams))),
            params.sonar,
        )
    return Observation(encoder_counts=counts, fix_pose=fix, sonar_gap_m=gaps)


def broadcast(
    state: WorldState, senders: IntArray, params: WorldParams, noise: WorldNoise
) -> tuple[WorldState, FrameFates]:
    """The fate of one frame from each of `senders` (S,) on its links to every robot.

    One draw per link (sender x receiver), self-links included so that the draws do not depend
    on who the sender is; a link's burst state moves only when a frame crosses it.  With a
    network fault active, each link has its own profile (`params.link_table`).
    """
    if senders.size == 0:
        empty = np.zeros(noise.batch_shape + (0, state.robot_count))
        return state, FrameFates(senders=senders, delivered=empty.astype(bool), delay_s=empty)
    positions = state.bodies.pose[..., :2]
    length_m = None
    if params.link.range_m is not None:
        d = positions[..., senders, None, :] - positions[..., None, :, :]
        length_m = np.hypot(d[..., 0], d[..., 1])
    links = params.link if params.link_table is None else params.link_table.rows(senders)
    draw = draw_links(links, state.link_bad[..., senders, :], length_m, noise.radio)
    link_bad = state.link_bad.copy()
    link_bad[..., senders, :] = draw.in_bad_state
    not_self = np.arange(state.robot_count) != senders[:, None]
    fates = FrameFates(senders=senders, delivered=draw.delivered & not_self, delay_s=draw.delay_s)
    return replace(state, link_bad=link_bad), fates


def step_world(
    state: WorldState, inputs: WorldInputs, params: WorldParams, noise: WorldNoise
) -> tuple[WorldState, FrameFates]:
    """One step: the senders' frames meet the radio, then the bodies move and collide."""
    state, fates = broadcast(state, inputs.senders, params, noise)
    n = state.robot_count
    bodies = state.bodies
    duty = np.asarray(inputs.duty, dtype=np.float64)
    sub_dt_s = inputs.dt_s / inputs.physics_substeps
    for _ in range(inputs.physics_substeps):
        slip_noise = noise.slip.standard_normal(noise.batch_shape + (n, 4))
        bodies = step_bodies(bodies, duty, sub_dt_s, slip_noise, params.body)
    positions, report = resolve_contacts(
        bodies.pose[..., :2],
        params.body.body_radius_m,
        params.obstacle_centres_m,
        params.obstacle_radii_m,
    )
    pose = bodies.pose.copy()
    pose[..., :2] = positions
    bodies = replace(bodies, pose=pose)
    contacts = np.concatenate((report.robot_robot, report.robot_obstacle), axis=-1)
    return replace(state, bodies=bodies, contacts=contacts), fates


class MetricsOracle(MetricsAccumulator):
    """`MetricsAccumulator` whose sample update is the numpy statement of the same figures."""

    def update(
        self,
        t_s: float,
        true_pose: FloatArray,
        trajectory_pose: FloatArray,
        contacts: BoolArray | None = None,
    ) -> FloatArray:
        """Add one sample; returns the per-robot errors (..., N, 3) for plotting or logging.

        contacts: (..., N, N + M) which pairs touch now, as reported by the physics; if omitted
        they are derived from the gaps.
        """
        cfg = self.config
        reference = reference_points(true_pose, trajectory_pose, self.layout, self.leader_index)
        errors = sample_errors(true_pose, reference)
        near = obstacle_gaps(reference[..., :2], self.obstacle_centres_m, self.obstacle_radii_m)
        limit = cfg.apf_influence_m + 2.0 * cfg.body_radius_m
        near_any = np.any(near <= limit, axis=-1)
        self.last_near_obstacle_s = np.where(near_any, t_s, self.last_near_obstacle_s)

        rgaps = robot_gaps(true_pose[..., :2], cfg.body_radius_m)
        ogaps = obstacle_gaps(true_pose[..., :2], self.obstacle_centres_m, self.obstacle_radii_m)
        ogaps = ogaps - cfg.body_radius_m
        self.min_robot_gap_m = np.minimum(self.min_robot_gap_m, np.min(rgaps, axis=(-2, -1)))
        if ogaps.shape[-1]:
            self.min_obstacle_gap_m = np.minimum(
                self.min_obstacle_gap_m, np.min(ogaps, axis=(-2, -1))
            )
        if contacts is None:
            contacts = np.concatenate((rgaps < 0.0, ogaps < 0.0), axis=-1)
        previous = self._previous_contacts
        onset = contacts if previous is None else contacts & ~previous
        self._previous_contacts = contacts
        n = len(self.layout.names)
        upper = np.triu(np.ones((n, n), dtype=bool), k=1)
        rr_onsets = np.sum(onset[..., :n] & upper, axis=(-2, -1))
        ro_onsets = np.sum(onset[..., n:], axis=(-2, -1))
        self.collisions += rr_onsets + ro_onsets

        if t_s >= cfg.steady_state_start_s:
            nominal = (t_s - self.last_near_obstacle_s) >= cfg.nominal_hold_s
            pos_sq = errors[..., 0] ** 2 + errors[..., 1] ** 2
            head_sq = errors[..., 2] ** 2
            leads = np.arange(len(self.layout.names)) == self.leader_index
            follows = ~leads
            self.sum_sq_position_all += np.where(follows, pos_sq, 0.0)
            self.sum_sq_heading_all += np.where(follows, head_sq, 0.0)
            self.count_all += follows
            self.sum_sq_position_nominal += np.where(nominal & follows, pos_sq, 0.0)
            self.sum_sq_heading_nominal += np.where(nominal & follows, head_sq, 0.0)
            self.count_nominal += nominal & follows
            self.sum_sq_position_all_lead += np.where(leads, pos_sq, 0.0)
            self.sum_sq_heading_all_lead += np.where(leads, head_sq, 0.0)
            self.count_all_lead += leads
            self.sum_sq_position_nominal_lead += np.where(nominal & leads, pos_sq, 0.0)
            self.sum_sq_heading_nominal_lead += np.where(nominal & leads, head_sq, 0.0)
            self.count_nominal_lead += nominal & leads
            pos = np.where(follows, np.sqrt(pos_sq), 0.0)
            self.max_position_all = np.maximum(self.max_position_all, pos)
            self.max_position_nominal = np.maximum(
                self.max_position_nominal, np.where(nominal, pos, 0.0)
            )
        if t_s >= cfg.fitness_window_start_s:
            self.sum_abs_error += np.sum(np.abs(errors), axis=(-2, -1))
            self.count_fitness += 1.0
        self.last_t_s = t_s
        return errors


class BatchRadio:
    """Delivers each robot's broadcast state to the others, as the world step decided.

    Frames wait in a small per-sender ring until their arrival time; a receiver keeps the
    newest state it has received from each peer (older frames arriving late are ignored).
    """

    def __init__(
        self,
        batch_shape: tuple[int, ...],
        robot_count: int,
        profile: LinkProfile,
        broadcast_period_s: float,
    ) -> None:
        b, n = batch_shape, robot_count
        self.slots = int(np.ceil(profile.max_delay_s / broadcast_period_s)) + 2
        k = self.slots
        self.payload = np.zeros((k,) + b + (n, 6))
        self.stamp_s = np.full((k, n), -np.inf)
        self.arrival_s = np.full((k,) + b + (n, n), np.inf)
        self.pending = np.zeros((k,) + b + (n, n), dtype=bool)
        self.next_slot = np.zeros(n, dtype=np.int64)
        self.peer_state = np.zeros(b + (n, n, 6))  # receiver, sender
        self.peer_stamp_s = np.full(b + (n, n), -np.inf)
        self.sent = 0
        self.delivered = np.zeros(b, dtype=np.int64)

    def post(self, t_s: float, fates: FrameFates, state: FloatArray) -> None:
        """The senders' `state` (..., N, 6) leaves at t_s; `fates` says which links carry it."""
        senders = fates.senders
        if senders.size == 0:
            return
        slot = self.next_slot[senders] % self.slots
        self.next_slot[senders] += 1
        self.payload[slot, ..., senders, :] = np.moveaxis(state[..., senders, :], -2, 0)
        self.stamp_s[slot, senders] = t_s
        links = self.arrival_s.shape[1:-2] + (senders.size, self.arrival_s.shape[-1])
        arrival = t_s + np.broadcast_to(fates.delay_s, links)
        self.arrival_s[slot, ..., senders, :] = np.moveaxis(arrival, -2, 0)
        self.pending[slot, ..., senders, :] = np.moveaxis(
            np.broadcast_to(fates.delivered, links), -2, 0
        )
        self.sent += int(senders.size)

    def deliver(self, t_s: float) -> None:
        """Move every frame due by t_s into the receivers' peer tables."""
        due = self.pending & (self.arrival_s <= t_s)
        if not due.any():
            return
        stamps = np.broadcast_to(
            self.stamp_s[
                (slice(None),)
                + (None,) * (due.ndim - 3)
                + (
                    slice(None),
                    None,
                )
            ],
            due.shape,
        )
        candidate = np.where(due, stamps, -np.inf)  # (K, ..., tx, rx)
        best = np.argmax(candidate, axis=0)
        best_stamp = np.max(candidate, axis=0)  # (..., tx, rx)
        newer = best_stamp > np.swapaxes(self.peer_stamp_s, -1, -2)
        self.delivered += np.sum(due, axis=(0, -2, -1))
        self.pending &= ~due
        if not newer.any():
            return
        payload = np.take_along_axis(
            self.payload[..., None, :],  # (K, ..., tx, 1, 6)
            best[None, ..., None],
            axis=0,
        )[0]  # (..., tx, rx, 6)
        table = np.swapaxes(self.peer_state, -2, -3)  # view (..., tx, rx, 6)
        np.copyto(table, payload, where=newer[..., None])
        stamp_view = np.swapaxes(self.peer_stamp_s, -1, -2)
        np.copyto(stamp_view, best_stamp, where=newer)


def run_batch_oracle(
    scenario: Scenario,
    batch_size: int = 1,
    rule_base: FuzzyRuleBase | None = None,
    controller: ControllerParams | None = None,
    shared_noise: bool = False,
    record_trace: bool = False,
    physics_substeps: int = 1,
    seed: int | None = None,
    duration_s: float | None = None,
) -> BatchResult:
    """`services.sim.batch.run_batch` tick by tick in numpy: the same results from the same seed.

    rule_base: one scheduler for all runs, or a batch with leading axis `batch_size`
    (defaults to the scenario's).  controller: overrides the scenario's controller parameters.
    """
    if batch_size < 1:
        raise ValueError("batch_size must be at least 1")
    if physics_substeps < 1:
        raise ValueError("physics_substeps must be at least 1")
    params = controller if controller is not None else scenario.controller_params()
    world_params = WorldParams.from_scenario(scenario, params.sonar_beam_angles_rad)
    dt = params.control_period_s
    ticks = round((duration_s if duration_s is not None else scenario.duration_s) / dt)

    names = scenario.robot_names
    n = len(names)
    b = (batch_size,)
    noise = WorldNoise.spawn(
        np.random.default_rng(scenario.seed if seed is None else seed),
        (1,) if shared_noise else b,
    )
    layout = FormationLayout.from_scenario(scenario)
    role = RobotRole(
        is_leader=np.broadcast_to(np.arange(n) == layout.leader_index, b + (n,)),
        slot_distance_m=layout.slot_distance_m,
        slot_angle_rad=layout.slot_angle_rad,
    )
    base = rule_base if rule_base is not None else load_rule_base(scenario)
    if base.error_centres.ndim == 1:
        rules = base  # one scheduler for every robot of every run
    elif base.error_centres.shape[0] == batch_size:
        rules = base.expand_dims((1,))  # (B, 1, 7): one per run, for each of its robots
    else:
        raise ValueError("a batched rule base needs a leading axis of length batch_size")
    rule_count = np.broadcast_to(np.asarray(base.rule_count), b) * n

    trajectory = scenario.trajectory.build()
    world = WorldState.at_rest(
        np.broadcast_to(scenario.initial_poses(), b + (n, 3)).copy(), noise.batch_shape
    )
    state = ControllerState.initial(b + (n,), len(world_params.beam_angles_rad))
    radio = BatchRadio(b, n, scenario.radio.link, 1.0 / scenario.radio.broadcast_rate_hz)
    broadcast_every = max(1, round(1.0 / (scenario.radio.broadcast_rate_hz * dt)))
    fix_every = max(1, round(1.0 / (world_params.positioning.rate_hz * dt)))
    sonar_every = max(1, round(1.0 / (world_params.sonar.rate_hz * dt)))
    sonar_gap = np.full(b + (n, len(world_params.beam_angles_rad)), np.inf)
    fix_pose = np.zeros(b + (n, 3))
    fix_valid = np.ones(b + (n,), dtype=bool)
    no_fix = np.zeros(b + (n,), dtype=bool)
    peer_is_leader = np.arange(n) == layout.leader_index
    robot_index = np.arange(n)
    metrics = MetricsOracle(
        b,
        layout,
        world_params.obstacle_centres_m,
        world_params.obstacle_radii_m,
        scenario.metrics_config(),
    )
    trace = Trace() if record_trace else None

    for k in range(ticks):
        t = k * dt
        radio.deliver(t)
        fix_due = k % fix_every == 0
        sonar_due = k % sonar_every == 0
        seen = sense_world(world, world_params, noise, fix_due, sonar_due)
        if seen.fix_pose is not None:
            fix_pose = seen.fix_pose
        if seen.sonar_gap_m is not None:
            sonar_gap = seen.sonar_gap_m
        reference_pose, reference_rate = trajectory.evaluate(t)
        peer = radio.peer_state
        inputs = ControlInputs(
            t_s=t,
            encoder_counts=seen.encoder_counts,
            fix_pose=fix_pose,
            fix_valid=fix_valid if fix_due else no_fix,
            sonar_range_m=sonar_gap,
            sonar_fresh=sonar_due,
            peer_pose=peer[..., :3],
            peer_rate=peer[..., 3:],
            peer_stamp_s=radio.peer_stamp_s,
            peer_valid=np.isfinite(radio.peer_stamp_s),
            peer_is_leader=peer_is_leader,
            reference_pose=reference_pose,
            reference_rate=reference_rate,
        )
        state, out = control_step(state, inputs, role, rules, params)
        errors = metrics.update(t, world.bodies.pose, reference_pose, world.contacts)
        if trace is not None:
            trace.t_s.append(t)
            trace.true_pose.append(world.bodies.pose.copy())
            trace.estimated_pose.append(state.estimator.pose.copy())
            trace.desired_pose.append(out.desired_pose)
            trace.trajectory_pose.append(reference_pose)
            trace.errors.append(errors)
            trace.delta_k.append(out.delta_k)
            trace.kp.append(out.kp)
        senders = robot_index[(k + robot_index) % broadcast_every == 0]
        step = WorldInputs(
            duty=out.duty, dt_s=dt, senders=senders, physics_substeps=physics_substeps
        )
        world, fates = step_world(world, step, world_params, noise)
        if senders.size:
            payload = np.concatenate((state.estimator.pose, state.estimator.rate), axis=-1)
            radio.post(t, fates, payload)

    return BatchResult(
        scenario=scenario,
        summaries=metrics.summaries(),
        metrics=metrics,
        rule_count=np.asarray(rule_count, dtype=np.int64),
        trace=trace,
        radio_sent=radio.sent,
        radio_delivered=radio.delivered,
    )

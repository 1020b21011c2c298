"""Batch simulator: B runs of one scenario x N robots, stepped together in numpy.

Each control tick (100 Hz by default) does what the swarm's processes do, in this order:
deliver radio frames that are due, synthesise sensors from ground truth (encoders every tick,
positioning fix and sonar at their own rates), run every robot's `control_step` (the same
function the firmware runs), broadcast each robot's state at the radio rate, record metrics,
then advance the physics by one control period with the duties held (`step_bodies` is exact
for a held duty; `physics_substeps` splits the period for comparison).

The B runs differ by their fuzzy schedulers (a batched rule base) and, unless
`shared_noise=True`, by their noise.  Shared noise gives every run the same disturbances
(common random numbers), which is what a tuner comparing candidates wants.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    RobotRole,
    control_step,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario, load_rule_base
from world.metrics import FormationLayout, MetricsAccumulator
from world.physics import BodyState, encoder_counts, resolve_contacts, step_bodies
from world.radio import draw_links
from world.sensors import pose_fix, sonar_gaps

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass
class Trace:
    """Time series of a batch run, sampled every control tick: arrays (T, B, N, ...)."""

    t_s: list[float] = field(default_factory=list)
    true_pose: list[FloatArray] = field(default_factory=list)
    estimated_pose: list[FloatArray] = field(default_factory=list)
    desired_pose: list[FloatArray] = field(default_factory=list)
    trajectory_pose: list[FloatArray] = field(default_factory=list)
    errors: list[FloatArray] = field(default_factory=list)
    delta_k: list[FloatArray] = field(default_factory=list)
    kp: list[FloatArray] = field(default_factory=list)

    def arrays(self) -> dict[str, FloatArray]:
        return {
            "t_s": np.asarray(self.t_s),
            "true_pose": np.stack(self.true_pose),
            "estimated_pose": np.stack(self.estimated_pose),
            "desired_pose": np.stack(self.desired_pose),
            "trajectory_pose": np.stack(self.trajectory_pose),
            "errors": np.stack(self.errors),
            "delta_k": np.stack(self.delta_k),
            "kp": np.stack(self.kp),
        }


@dataclass
class BatchResult:
    scenario: Scenario
    summaries: list[dict[str, object]]
    metrics: MetricsAccumulator
    rule_count: NDArray[np.int64]
    trace: Trace | None
    radio_sent: int
    radio_delivered: NDArray[np.int64]


class BatchRadio:
    """Delivers each robot's broadcast state to the others through a link profile.

    Frames wait in a small per-sender ring until their arrival time; a receiver keeps the
    newest state it has received from each peer (older frames arriving late are ignored).
    """

    def __init__(
        self,
        batch_shape: tuple[int, ...],
        robot_count: int,
        profile: LinkProfile,
        broadcast_period_s: float,
        shared_noise: bool,
    ) -> None:
        b, n = batch_shape, robot_count
        self.profile = profile
        self.slots = int(np.ceil(profile.max_delay_s / broadcast_period_s)) + 2
        k = self.slots
        self.payload = np.zeros((k,) + b + (n, 6))
        self.stamp_s = np.full((k, n), -np.inf)
        self.arrival_s = np.full((k,) + b + (n, n), np.inf)
        self.pending = np.zeros((k,) + b + (n, n), dtype=bool)
        self.next_slot = np.zeros(n, dtype=np.int64)
        self.peer_state = np.zeros(b + (n, n, 6))  # receiver, sender
        self.peer_stamp_s = np.full(b + (n, n), -np.inf)
        self.bad_state = np.zeros(((1,) if shared_noise else b) + (n, n), dtype=bool)
        self.not_self = ~np.eye(n, dtype=bool)
        self.sent = 0
        self.delivered = np.zeros(b, dtype=np.int64)
        self.noise_shape = ((1,) if shared_noise else b) + (n, n)

    def broadcast(
        self,
        t_s: float,
        senders: NDArray[np.int64],
        state: FloatArray,
        positions_m: FloatArray,
        rng: np.random.Generator,
    ) -> None:
        """Robots `senders` broadcast `state` (..., N, 6) at t_s; links drawn per receiver."""
        if senders.size == 0:
            return
        d = positions_m[..., :, None, :] - positions_m[..., None, :, :]
        length = np.hypot(d[..., 0], d[..., 1]) if self.profile.range_m is not None else None
        draw = draw_links(self.profile, self.bad_state, length, rng)
        self.bad_state = draw.in_bad_state
        slot = self.next_slot[senders] % self.slots
        self.next_slot[senders] += 1
        self.payload[slot, ..., senders, :] = np.moveaxis(state[..., senders, :], -2, 0)
        self.stamp_s[slot, senders] = t_s
        arrival = t_s + np.broadcast_to(draw.delay_s, self.arrival_s.shape[1:])
        ok = np.broadcast_to(draw.delivered & self.not_self, self.pending.shape[1:])
        self.arrival_s[slot, ..., senders, :] = np.moveaxis(arrival[..., senders, :], -2, 0)
        self.pending[slot, ..., senders, :] = np.moveaxis(ok[..., senders, :], -2, 0)
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


def run_batch(
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
    """Simulate `batch_size` runs of `scenario` and return their metrics.

    rule_base: one scheduler for all runs, or a batch with leading axis `batch_size`
    (defaults to the scenario's).  controller: overrides the scenario's controller parameters.
    """
    if batch_size < 1:
        raise ValueError("batch_size must be at least 1")
    if physics_substeps < 1:
        raise ValueError("physics_substeps must be at least 1")
    params = controller if controller is not None else scenario.controller_params()
    body_params = scenario.robot_body
    sonar_params = scenario.sensors.sonar
    fix_params = scenario.sensors.positioning
    dt = params.control_period_s
    ticks = round((duration_s if duration_s is not None else scenario.duration_s) / dt)
    rng = np.random.default_rng(scenario.seed if seed is None else seed)

    names = scenario.robot_names
    n = len(names)
    b = (batch_size,)
    noise_b = (1,) if shared_noise else b
    layout = FormationLayout.from_scenario(scenario)
    role = RobotRole(
        is_leader=np.broadcast_to(np.arange(n) == layout.leader_index, b + (n,)),
        slot_distance_m=layout.slot_distance_m,
        slot_angle_rad=layout.slot_angle_rad,
    )
    base = rule_base if rule_base is not None else load_rule_base(scenario)
    if base.error_centres.ndim == 1:
        rules = base.expand_dims((0, 1, 2))  # (1, 1, 1, 7): batch, robot, axis
    elif base.error_centres.shape[0] == batch_size:
        rules = base.expand_dims((1, 2))
    else:
        raise ValueError("a batched rule base needs a leading axis of length batch_size")
    rule_count = np.broadcast_to(np.asarray(base.rule_count), b) * n

    trajectory = scenario.trajectory.build()
    obstacle_centres, obstacle_radii = scenario.obstacle_arrays()
    m = len(obstacle_radii)
    beams = np.asarray(params.sonar_beam_angles_rad)
    body_r = body_params.body_radius_m
    target_radii = np.concatenate([obstacle_radii, np.full(n, body_r)])
    target_valid = np.concatenate(
        [np.ones((n, m), dtype=bool), ~np.eye(n, dtype=bool)], axis=1
    )  # (N, M + N): a robot's sonar does not see itself

    bodies = BodyState.at_rest(np.broadcast_to(scenario.initial_poses(), b + (n, 3)).copy())
    state = ControllerState.initial(b + (n,), len(beams))
    radio = BatchRadio(
        b, n, scenario.radio.link, 1.0 / scenario.radio.broadcast_rate_hz, shared_noise
    )
    broadcast_every = max(1, round(1.0 / (scenario.radio.broadcast_rate_hz * dt)))
    fix_every = max(1, round(1.0 / (fix_params.rate_hz * dt)))
    sonar_every = max(1, round(1.0 / (sonar_params.rate_hz * dt)))
    sonar_gap = np.full(b + (n, len(beams)), np.inf)
    fix_pose = np.zeros(b + (n, 3))
    no_fix = np.zeros(b + (n,), dtype=bool)
    peer_is_leader = np.arange(n) == layout.leader_index
    robot_index = np.arange(n)
    metrics = MetricsAccumulator(
        b, layout, obstacle_centres, obstacle_radii, scenario.metrics_config()
    )
    contacts: BoolArray | None = None
    trace = Trace() if record_trace else None
    sub_dt = dt / physics_substeps

    for k in range(ticks):
        t = k * dt
        radio.deliver(t)
        counts = encoder_counts(bodies.wheel_angle_rad, body_params.encoder_counts_per_rev)
        fix_due = k % fix_every == 0
        if fix_due:
            fix_pose = pose_fix(bodies.pose, rng.standard_normal(noise_b + (n, 3)), fix_params)
        sonar_due = k % sonar_every == 0
        if sonar_due:
            targets = np.concatenate(
                [np.broadcast_to(obstacle_centres, b + (m, 2)), bodies.pose[..., :2]], axis=-2
            )
            sonar_gap = sonar_gaps(
                bodies.pose,
                beams,
                targets[..., None, :, :],
                target_radii,
                target_valid,
                body_r,
                rng.standard_normal(noise_b + (n, len(beams))),
                sonar_params,
            )
        reference_pose, reference_rate = trajectory.evaluate(t)
        peer = radio.peer_state
        inputs = ControlInputs(
            t_s=t,
            encoder_counts=counts,
            fix_pose=fix_pose,
            fix_valid=np.broadcast_to(fix_due, b + (n,)) if fix_due else no_fix,
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
        senders = robot_index[(k + robot_index) % broadcast_every == 0]
        if senders.size:
            payload = np.concatenate((state.estimator.pose, state.estimator.rate), axis=-1)
            radio.broadcast(t, senders, payload, bodies.pose[..., :2], rng)
        errors = metrics.update(t, bodies.pose, reference_pose, contacts)
        if trace is not None:
            trace.t_s.append(t)
            trace.true_pose.append(bodies.pose.copy())
            trace.estimated_pose.append(state.estimator.pose.copy())
            trace.desired_pose.append(out.desired_pose)
            trace.trajectory_pose.append(reference_pose)
            trace.errors.append(errors)
            trace.delta_k.append(out.delta_k)
            trace.kp.append(out.kp)
        for _ in range(physics_substeps):
            bodies = step_bodies(
                bodies, out.duty, sub_dt, rng.standard_normal(noise_b + (n, 4)), body_params
            )
        positions, report = resolve_contacts(
            bodies.pose[..., :2], body_r, obstacle_centres, obstacle_radii
        )
        pose = bodies.pose.copy()
        pose[..., :2] = positions
        bodies = BodyState(
            pose=pose,
            wheel_speed_radps=bodies.wheel_speed_radps,
            wheel_angle_rad=bodies.wheel_angle_rad,
            slip=bodies.slip,
        )
        contacts = np.concatenate((report.robot_robot, report.robot_obstacle), axis=-1)

    return BatchResult(
        scenario=scenario,
        summaries=metrics.summaries(),
        metrics=metrics,
        rule_count=np.asarray(rule_count, dtype=np.int64),
        trace=trace,
        radio_sent=radio.sent,
        radio_delivered=radio.delivered,
    )

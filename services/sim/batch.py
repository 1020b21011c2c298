"""Batch simulator: B runs of one scenario x N robots, stepped together in numpy.

Each control tick (100 Hz by default) does what the swarm's processes do, in this order:
deliver radio frames that are due, synthesise sensors from ground truth (encoders every tick,
positioning fix and sonar at their own rates: `world.step.sense_world`), run every robot's
`control_step` (the same function the firmware runs), record metrics, then take one world step
(`world.step.step_world`, the same one the world process takes): the frames of the robots whose
broadcast is due meet the radio medium, and the bodies move for one control period with the
duties held (exact for a held duty; `physics_substeps` splits the period for comparison).

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
from world.step import (
    FrameFates,
    WorldInputs,
    WorldNoise,
    WorldParams,
    WorldState,
    sense_world,
    step_world,
)

FloatArray = NDArray[np.float64]


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
    metrics = MetricsAccumulator(
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

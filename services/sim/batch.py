"""Batch simulator: B runs of one scenario x N robots, stepped together by compiled kernels.

Each control tick (100 Hz by default) does what the swarm's processes do, in this order:
deliver radio frames that are due, synthesise sensors from ground truth (encoders every tick,
positioning fix and sonar at their own rates), run every robot's control step (the kernel the
firmware runs), record metrics (the accumulator's kernel), then take one world step: the frames
of the robots whose broadcast is due meet the radio medium, and the bodies move for one control
period with the duties held (exact for a held duty; `physics_substeps` splits the period for
comparison).  The world process takes the same steps through `world.step.sense_world` and
`step_world`, which run the same kernels.

The ticks run inside one compiled loop (services/sim/ticks.py), a chunk of ticks per call, with
the chunk's random numbers drawn beforehand in numpy from the same streams in the same order as
tick by tick; tests/world/oracle.py states the same loop in numpy (`run_batch_oracle`) and the
batch is tested against it.

The B runs differ by their fuzzy schedulers (a batched rule base) and, unless
`shared_noise=True`, by their noise.  Shared noise gives every run the same disturbances
(common random numbers), which is what a tuner comparing candidates wants.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.controller import (
    ControllerParams,
    ControllerState,
    RobotRole,
    output_rows,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase
from robot_firmware.control.rows import rows_of
from services.sim.ticks import run_ticks
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario, load_rule_base
from world.metrics import FormationLayout, MetricsAccumulator, metrics_constants
from world.physics import body_constants, counts_per_radian
from world.radio import LinkTable
from world.sensors import fix_noise_std, sonar_constants
from world.step import WorldNoise, WorldParams

FloatArray = NDArray[np.float64]
CHUNK_VALUES = 1 << 20
"""About how many random numbers and trace values one call of the tick loop holds at most."""


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


def ring_slots(profile: LinkProfile, broadcast_period_s: float) -> int:
    """Frames each sender keeps in flight: enough for the longest delay, and two more."""
    return int(np.ceil(profile.max_delay_s / broadcast_period_s)) + 2


def link_constants(
    profile: LinkProfile,
) -> tuple[float, float, float, bool, float, float, float, float, float]:
    """A uniform link profile as the tick loop takes it (`world.radio.link_delivery`)."""
    t = LinkTable.from_profile(profile)
    return (
        float(t.latency_ms), float(t.jitter_ms), float(t.loss), bool(t.burst),
        float(t.good_to_bad), float(t.bad_to_good), float(t.loss_in_good), float(t.loss_in_bad),
        math.inf if t.range_m is None else float(t.range_m),
    )  # fmt: skip


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
    threads: int | None = None,
) -> BatchResult:
    """Simulate `batch_size` runs of `scenario` and return their metrics.

    rule_base: one scheduler for all runs, or a batch with leading axis `batch_size`
    (defaults to the scenario's).  controller: overrides the scenario's controller parameters.
    threads: how many threads share the runs (`_parts`; None: one per CPU, at most
    `MAX_THREADS`, and one for batches under `MIN_RUNS_PER_THREAD` runs a thread); the results
    are the same bit for bit whatever it is.
    """
    if batch_size < 1:
        raise ValueError("batch_size must be at least 1")
    if threads is not None and threads < 1:
        raise ValueError("threads must be at least 1")
    if physics_substeps < 1:
        raise ValueError("physics_substeps must be at least 1")
    params = controller if controller is not None else scenario.controller_params()
    world_params = WorldParams.from_scenario(scenario, params.sonar_beam_angles_rad)
    dt = params.control_period_s
    ticks = round((duration_s if duration_s is not None else scenario.duration_s) / dt)

    n = len(scenario.robot_names)
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
    metrics = MetricsAccumulator(
        b,
        layout,
        world_params.obstacle_centres_m,
        world_params.obstacle_radii_m,
        scenario.metrics_config(),
    )
    loop = _TickLoop(scenario, params, world_params, noise, role, rules, metrics)
    broadcast_every = max(1, round(1.0 / (scenario.radio.broadcast_rate_hz * dt)))
    fix_every = max(1, round(1.0 / (world_params.positioning.rate_hz * dt)))
    sonar_every = max(1, round(1.0 / (world_params.sonar.rate_hz * dt)))
    schedule = (float(dt), broadcast_every, fix_every, sonar_every, physics_substeps)
    burst = loop.link[3]
    robots = np.arange(n)
    noise_worlds = noise.batch_shape[0]
    beams = len(world_params.beam_angles_rad)
    per_tick = noise_worlds * n * (4 * physics_substeps + 3 + beams + 3 * n)
    per_tick += 6 * batch_size * n * 3 if record_trace else 0
    chunk = max(1, CHUNK_VALUES // per_tick)
    trace = Trace() if record_trace else None
    sent = 0
    parts = loop.parts(_thread_count(threads, batch_size))
    pool = ThreadPoolExecutor(max_workers=len(parts)) if len(parts) > 1 else None
    for first in range(0, ticks, chunk):
        count = min(chunk, ticks - first)
        k = np.arange(first, first + count)
        t = k * dt
        reference_pose, reference_rate = trajectory.evaluate(t)
        senders = np.count_nonzero((k[:, None] + robots) % broadcast_every == 0, axis=1)
        sent += int(senders.sum())
        uniforms = (3 if burst else 2) * noise_worlds * n * int(senders.sum())
        draws = (
            noise.fix.standard_normal(
                (np.count_nonzero(k % fix_every == 0),) + noise.batch_shape + (n, 3)
            ),
            noise.sonar.standard_normal(
                (np.count_nonzero(k % sonar_every == 0),) + noise.batch_shape + (n, beams)
            ),
            noise.slip.standard_normal((count * physics_substeps,) + noise.batch_shape + (n, 4)),
            noise.radio.random(uniforms),
        )
        recorded = tuple(
            np.empty((count if record_trace else 0, batch_size, n, 3)) for _ in range(6)
        )
        reference = (np.ascontiguousarray(reference_pose), np.ascontiguousarray(reference_rate))
        calls = []
        for part in parts:
            call = partial(
                run_ticks,
                first, count, part.first_world, part.stop_world, schedule, reference, part.world,
                part.world_constants, loop.controller, part.radio, loop.link, part.metrics, draws,
                recorded, record_trace,
            )  # fmt: skip
            calls.append(call)
        if pool is None:
            calls[0]()
        else:
            for done in [pool.submit(call) for call in calls]:
                done.result()
            loop.gather(parts)
        if trace is not None:
            trace.t_s.extend(t.tolist())
            for name, values in zip(_TRACED, recorded, strict=True):
                getattr(trace, name).extend(values)
            trace.trajectory_pose.extend(np.array(reference_pose))
    if pool is not None:
        pool.shutdown()
    if ticks:
        metrics.samples_taken((ticks - 1) * dt, loop.previous_contacts)

    return BatchResult(
        scenario=scenario,
        summaries=metrics.summaries(),
        metrics=metrics,
        rule_count=np.asarray(rule_count, dtype=np.int64),
        trace=trace,
        radio_sent=sent,
        radio_delivered=loop.delivered,
    )


_TRACED = ("true_pose", "estimated_pose", "desired_pose", "errors", "delta_k", "kp")
"""The trace fields the tick loop writes, in its order."""

MAX_THREADS = 2
"""The most threads a batch is split over (the machines this runs on have 2 cores)."""
MIN_RUNS_PER_THREAD = 8
"""Fewer runs than this per thread and the batch runs on one: a thread's hand-over per chunk
costs more than it saves."""


def _thread_count(threads: int | None, batch_size: int) -> int:
    if threads is None:
        threads = min(MAX_THREADS, os.cpu_count() or 1)
    return max(1, min(threads, batch_size // MIN_RUNS_PER_THREAD))


@dataclass(frozen=True)
class _Part:
    """One thread's runs first_world .. stop_world - 1 and its arguments of `run_ticks`: the
    batch's arrays, with copies of what all runs share (`run_ticks`)."""

    first_world: int
    stop_world: int
    world: tuple[Any, ...]
    world_constants: tuple[Any, ...]
    radio: tuple[Any, ...]
    metrics: tuple[Any, ...]


class _TickLoop:
    """The arrays of one batch run as `services.sim.ticks.run_ticks` takes them (rows
    run-major: r = b·N + i)."""

    def __init__(
        self,
        scenario: Scenario,
        params: ControllerParams,
        world: WorldParams,
        noise: WorldNoise,
        role: RobotRole,
        rules: FuzzyRuleBase,
        metrics: MetricsAccumulator,
    ) -> None:
        f8, i8, b1 = np.float64, np.int64, np.bool_
        n = len(scenario.robot_names)
        batch = metrics.count_all.shape[:-1]
        worlds = batch[0]
        rows = worlds * n
        m = len(world.obstacle_radii_m)
        beams = len(world.beam_angles_rad)
        body_radius_m = float(world.body.body_radius_m)
        pose = np.zeros((worlds, n, 3))
        pose[...] = scenario.initial_poses()
        self.previous_contacts = np.zeros((worlds, n, n + m), dtype=b1)
        self.world = (
            pose,
            np.zeros((worlds, n, 4)),
            np.zeros((worlds, n, 4)),
            np.zeros((worlds, n, 4)),
            np.zeros(noise.batch_shape + (n, n), dtype=b1),
            np.zeros((worlds, n, n + m), dtype=b1),
            np.zeros(1, dtype=b1),
        )
        obstacle_centres = np.ascontiguousarray(world.obstacle_centres_m, dtype=f8).reshape(-1, 2)
        obstacle_radii = np.ascontiguousarray(world.obstacle_radii_m, dtype=f8).reshape(-1)
        self.world_constants = (
            body_constants(world.body),
            body_radius_m,
            counts_per_radian(world.body.encoder_counts_per_rev),
            fix_noise_std(world.positioning),
            sonar_constants(world.sonar, body_radius_m),
            np.ascontiguousarray(world.beam_angles_rad, dtype=f8),
            np.concatenate((obstacle_centres, np.zeros((n, 2)))),
            np.concatenate((obstacle_radii, np.full(n, body_radius_m))),
            obstacle_centres,
            obstacle_radii,
        )

        set_a, set_b = output_rows(rows, beams, n), output_rows(rows, beams, n)
        initial = ControllerState.initial(batch + (n,), beams)
        est, pid = initial.estimator, initial.pid
        side = np.zeros(batch + (n, n))
        starting = rows_of(
            batch + (n,),
            (est.pose, 1, f8), (est.rate, 1, f8), (pid.integral, 1, f8),
            (pid.previous_error, 1, f8), (pid.error_rate, 1, f8),
            (initial.avoidance_offset_m, 1, f8), (initial.echo_points_m, 2, f8), (side, 1, f8),
            (est.previous_counts, 1, i8), (est.localised, 0, b1), (pid.saturated, 0, b1),
            (pid.started, 0, b1), (initial.echo_valid, 1, b1),
        )  # fmt: skip
        for target, value in zip(set_a[0][:8] + set_a[1][:5], starting, strict=True):
            target[...] = value
        leader = np.arange(n) == metrics.layout.leader_index
        role_rows = rows_of(
            batch + (n,),
            (np.broadcast_to(leader, (n, n)), 1, b1), (np.zeros((n, n), dtype=b1), 1, b1),
            (role.is_leader, 0, b1), (role.slot_distance_m, 0, f8), (role.slot_angle_rad, 0, f8),
        )  # fmt: skip
        rule_rows = rows_of(
            batch + (n,),
            (rules.error_centres, 1, f8), (rules.rate_centres, 1, f8),
            (rules.error_set_count, 0, i8), (rules.rate_set_count, 0, i8),
            (rules.rule_outputs, 2, f8),
        )  # fmt: skip
        self.controller = (
            params.constants,
            set_a,
            set_b,
            (
                np.zeros((rows, 3)),
                np.zeros(rows, dtype=b1),
                np.full((rows, beams), np.inf),
                np.zeros((rows, 4), dtype=i8),
                np.zeros((rows, 3)),
                np.zeros((rows, 3)),
                np.zeros((rows, n), dtype=b1),
            ),
            tuple(np.ascontiguousarray(a) for a in role_rows),
            (np.zeros((rows, n, 3)), np.zeros((rows, n, 3)), np.full((rows, n), -np.inf)),
            tuple(np.ascontiguousarray(a) for a in rule_rows),
            np.zeros((rows, n), dtype=b1),
            np.zeros((rows, n, 3)),
            np.zeros(3),
        )
        profile = scenario.radio.link
        slots = ring_slots(profile, 1.0 / scenario.radio.broadcast_rate_hz)
        self.delivered = np.zeros(worlds, dtype=i8)
        self.radio = (
            np.zeros((slots, worlds, n, 6)),
            np.full((slots, n), -np.inf),
            np.full((slots, worlds, n, n), np.inf),
            np.zeros((slots, worlds, n, n), dtype=b1),
            np.zeros(n, dtype=i8),
            self.delivered,
        )
        self.link = link_constants(profile)
        lead = metrics.leader_index
        distance_m, angle_rad = metrics.slots_relative_to(lead)
        per_robot, per_run = metrics.kernel_arrays(worlds)
        self.metrics = (
            per_robot,
            per_run,
            lead,
            distance_m,
            angle_rad,
            metrics_constants(metrics.config),
            self.previous_contacts,
            np.zeros(1, dtype=b1),
            np.zeros((worlds, n, 3)),
            np.zeros((worlds, n, n + m), dtype=b1),
            np.zeros(3 * n),
        )
        self.shared_links = noise.batch_shape[0] != worlds
        """Whether every run reads one noise element's link states (common random numbers)."""

    def parts(self, count: int) -> list[_Part]:
        """The runs split into `count` parts of (nearly) equal size; with one part, the batch's
        own arrays, else each with copies of what all runs share."""
        worlds = self.world[0].shape[0]
        bounds = [round(worlds * p / count) for p in range(count + 1)]
        if count == 1:
            return [_Part(0, worlds, self.world, self.world_constants, self.radio, self.metrics)]
        parts = []
        for first, stop in itertools.pairwise(bounds):
            world = list(self.world)
            if self.shared_links:
                world[4] = world[4].copy()
            world[6] = world[6].copy()  # contacts_known
            constants: list[Any] = list(self.world_constants)
            constants[6] = constants[6].copy()  # the sonar's targets
            radio = list(self.radio)
            radio[1], radio[4] = radio[1].copy(), radio[4].copy()  # the ring's stamps and slots
            metrics: list[Any] = list(self.metrics)
            metrics[7], metrics[10] = metrics[7].copy(), metrics[10].copy()
            parts.append(
                _Part(first, stop, tuple(world), tuple(constants), tuple(radio), tuple(metrics))
            )
        return parts

    def gather(self, parts: list[_Part]) -> None:
        """What all runs share back from the first part (every part evolved it alike)."""
        head = parts[0]
        if self.shared_links:
            self.world[4][...] = head.world[4]
        self.world[6][...] = head.world[6]
        self.radio[1][...] = head.radio[1]
        self.radio[4][...] = head.radio[4]
        self.metrics[7][...] = head.metrics[7]
        for part in parts:
            part.world[6][...] = head.world[6]
            part.metrics[7][...] = head.metrics[7]

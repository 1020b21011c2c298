"""The world of a live swarm: bodies, sensor synthesis and the radio medium, stepped in time.

The world process (and in-process tests that run real firmware on real fabric models) drive a
`WorldEngine`: it owns the ground truth of every robot body, turns it into what each robot's
pins see (`SenseMessage`: running encoder counts, sonar echo times, positioning fixes) and takes
back what the motor pins carry (PWM duty per wheel).  It is also the radio medium: frames are
opaque bytes, delivered to every other robot after the link profile's delay, or dropped.

Everything is pure: time advances only through `advance(duty, dt_ns)`, randomness comes from
a generator seeded by the scenario.  Physics uses the same `step_bodies` as the batch simulator,
and the metrics the same `MetricsAccumulator`, so a live run and `swarm sim` report the same
quantities.
"""

from __future__ import annotations

import heapq
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from robot_firmware.net.wire import FixSample, SenseMessage
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario
from world.metrics import FormationLayout, MetricsAccumulator
from world.physics import BodyState, encoder_counts, resolve_contacts, step_bodies
from world.radio import draw_links
from world.sensors import pose_fix, sonar_gaps

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

SPEED_OF_SOUND_MPS = 343.0
NS_PER_S = 1_000_000_000


@dataclass(order=True)
class _Frame:
    arrival_ns: int
    order: int
    receiver: int = field(compare=False)
    sender: int = field(compare=False)
    sent_ns: int = field(compare=False)
    payload: bytes = field(compare=False)


@dataclass
class RadioCounters:
    """Frames broadcast, delivered and dropped; latencies of the most recent deliveries."""

    sent: int = 0
    delivered: int = 0
    dropped: int = 0
    latencies_ns: deque[int] = field(default_factory=lambda: deque(maxlen=50_000))

    def latency_percentile_ms(self, q: float) -> float | None:
        if not self.latencies_ns:
            return None
        return float(np.percentile(np.asarray(self.latencies_ns), q)) / 1e6


def echo_times_from_gaps(gaps_m: FloatArray) -> list[tuple[float | None, ...]]:
    """Round-trip echo time per robot and transducer for gaps (n, beams); None = no echo."""
    return [
        tuple(None if not np.isfinite(g) else 2.0 * float(g) / SPEED_OF_SOUND_MPS for g in row)
        for row in gaps_m
    ]


class WorldEngine:
    """Ground truth, sensors and radio of one scenario's robots."""

    def __init__(self, scenario: Scenario, seed: int | None = None) -> None:
        self.scenario = scenario
        self.names = scenario.robot_names
        self.robot_count = len(self.names)
        self.rng = np.random.default_rng(scenario.seed if seed is None else seed)
        self.body_params = scenario.robot_body
        self.sonar_params = scenario.sensors.sonar
        self.fix_params = scenario.sensors.positioning
        self.beam_angles_rad = np.asarray(scenario.controller_params().sonar_beam_angles_rad)
        self.obstacle_centres_m, self.obstacle_radii_m = scenario.obstacle_arrays()
        self.bodies = BodyState.at_rest(scenario.initial_poses())
        self.t_ns = 0
        self.link: LinkProfile = scenario.radio.link
        self.radio = RadioCounters()
        self._queue: list[_Frame] = []
        self._order = 0
        self._bad_links = np.zeros(self.robot_count, dtype=bool)
        self.fix_period_ns = round(NS_PER_S / self.fix_params.rate_hz)
        self.sonar_period_ns = round(NS_PER_S / self.sonar_params.rate_hz)
        self.metrics_period_ns = round(scenario.controller_params().control_period_s * NS_PER_S)
        self._next_fix_ns = 0
        self._next_sonar_ns = 0
        self._sonar_echo_times_s = echo_times_from_gaps(
            np.full((self.robot_count, len(self.beam_angles_rad)), np.inf)
        )
        self._fixes: list[FixSample | None] = [None] * self.robot_count
        self._next_metrics_ns = 0
        self._contacts: BoolArray | None = None
        self.trajectory = scenario.trajectory.build()
        self.metrics = MetricsAccumulator(
            (),
            FormationLayout.from_scenario(scenario),
            self.obstacle_centres_m,
            self.obstacle_radii_m,
            scenario.metrics_config(),
        )
        self.fixes_cut = np.zeros(self.robot_count, dtype=bool)

    @property
    def t_s(self) -> float:
        return self.t_ns / NS_PER_S

    def sense(self) -> list[SenseMessage]:
        """What every robot's pins see now; fixes and sonar refresh at their own rates."""
        if self.t_ns >= self._next_sonar_ns:
            self._next_sonar_ns += self.sonar_period_ns
            n = self.robot_count
            m = len(self.obstacle_radii_m)
            targets = np.concatenate([self.obstacle_centres_m, self.bodies.pose[:, :2]], axis=0)
            radii = np.concatenate(
                [self.obstacle_radii_m, np.full(n, self.body_params.body_radius_m)]
            )
            valid = np.concatenate([np.ones((n, m), dtype=bool), ~np.eye(n, dtype=bool)], axis=1)
            gaps_m = sonar_gaps(
                self.bodies.pose,
                self.beam_angles_rad,
                np.broadcast_to(targets, (n, m + n, 2)),
                radii,
                valid,
                self.body_params.body_radius_m,
                self.rng.standard_normal((n, len(self.beam_angles_rad))),
                self.sonar_params,
            )
            self._sonar_echo_times_s = echo_times_from_gaps(gaps_m)
        fresh_fix = self.t_ns >= self._next_fix_ns
        if fresh_fix:
            self._next_fix_ns += self.fix_period_ns
            noisy = pose_fix(
                self.bodies.pose, self.rng.standard_normal((self.robot_count, 3)), self.fix_params
            )
            self._fixes = [
                FixSample(
                    float(p[0]),
                    float(p[1]),
                    float(p[2]),
                    self.t_ns,
                    valid=not bool(self.fixes_cut[i]),
                )
                for i, p in enumerate(noisy)
            ]
        counts = encoder_counts(
            self.bodies.wheel_angle_rad, self.body_params.encoder_counts_per_rev
        )
        messages = []
        for i in range(self.robot_count):
            messages.append(
                SenseMessage(
                    encoder_counts=tuple(int(c) for c in counts[i]),
                    sonar_echo_times_s=self._sonar_echo_times_s[i],
                    fix=self._fixes[i] if fresh_fix else None,
                    t_ns=self.t_ns,
                )
            )
        return messages

    def advance(self, duty: FloatArray, dt_ns: int) -> None:
        """Step the bodies by dt_ns with the given duties (N, 4); record metrics on schedule."""
        if self.t_ns >= self._next_metrics_ns:
            self._next_metrics_ns += self.metrics_period_ns
            reference, _ = self.trajectory.evaluate(self.t_s)
            self.metrics.update(self.t_s, self.bodies.pose, reference, self._contacts)
        dt_s = dt_ns / NS_PER_S
        self.bodies = step_bodies(
            self.bodies,
            np.asarray(duty, dtype=np.float64),
            dt_s,
            self.rng.standard_normal((self.robot_count, 4)),
            self.body_params,
        )
        positions, report = resolve_contacts(
            self.bodies.pose[:, :2],
            self.body_params.body_radius_m,
            self.obstacle_centres_m,
            self.obstacle_radii_m,
        )
        pose = self.bodies.pose.copy()
        pose[:, :2] = positions
        self.bodies = BodyState(
            pose=pose,
            wheel_speed_radps=self.bodies.wheel_speed_radps,
            wheel_angle_rad=self.bodies.wheel_angle_rad,
            slip=self.bodies.slip,
        )
        self._contacts = np.concatenate((report.robot_robot, report.robot_obstacle), axis=-1)
        self.t_ns += dt_ns

    def transmit(self, sender: int, payload: bytes) -> None:
        """A robot broadcasts `payload` now; each other robot gets it after its link's delay."""
        self.radio.sent += 1
        receivers = np.array([r for r in range(self.robot_count) if r != sender])
        if receivers.size == 0:
            return
        positions = self.bodies.pose[:, :2]
        length = np.hypot(*(positions[receivers] - positions[sender]).T)
        draw = draw_links(self.link, self._bad_links[receivers], length, self.rng)
        self._bad_links[receivers] = draw.in_bad_state
        for r, ok, delay_s in zip(receivers, draw.delivered, draw.delay_s, strict=True):
            if not ok:
                self.radio.dropped += 1
                continue
            self._order += 1
            heapq.heappush(
                self._queue,
                _Frame(
                    arrival_ns=self.t_ns + round(float(delay_s) * NS_PER_S),
                    order=self._order,
                    receiver=int(r),
                    sender=sender,
                    sent_ns=self.t_ns,
                    payload=payload,
                ),
            )

    def next_frame_due_ns(self) -> int | None:
        """When the next queued frame arrives (simulation ns), or None."""
        return self._queue[0].arrival_ns if self._queue else None

    def due_frames(self) -> list[tuple[int, int, bytes]]:
        """Frames that have arrived by now, as (receiver, sender, payload), oldest first."""
        out = []
        while self._queue and self._queue[0].arrival_ns <= self.t_ns:
            frame = heapq.heappop(self._queue)
            self.radio.delivered += 1
            self.radio.latencies_ns.append(frame.arrival_ns - frame.sent_ns)
            out.append((frame.receiver, frame.sender, frame.payload))
        return out

    def summary(self) -> dict[str, object]:
        return self.metrics.summaries()[0]

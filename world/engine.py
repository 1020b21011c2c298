"""The world of a live swarm: bodies, sensor synthesis and the radio medium, stepped in time.

The world process (and in-process tests that run real firmware on real fabric models) drive a
`WorldEngine`: it owns the ground truth of every robot body, turns it into what each robot's
pins see (`SenseMessage`: running encoder counts, sonar echo times, positioning fixes) and takes
back what the motor pins carry (PWM duty per wheel).  It is also the radio medium: frames are
opaque bytes, delivered to every other robot after the link's delay, or dropped.

The engine is the stateful shell around the batched world step of `world.step` with an empty
batch shape: `sense` is `sense_world`, `advance` is `step_world` with no senders, and
`transmit` is the step's radio half (`broadcast`) for one sender, because frames reach the world
whenever a robot sends one.  The batch simulator calls the same functions, so a live run and
`swarm sim` share physics, sensors, radio draws and noise streams, and the metrics are the same
`MetricsAccumulator`.  Time advances only through `advance(duty, dt_ns)`; randomness comes from
a generator seeded by the scenario.
"""

from __future__ import annotations

import heapq
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from robot_firmware.net.wire import FixSample, SenseMessage
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario
from world.metrics import FormationLayout, MetricsAccumulator
from world.physics import BodyState
from world.step import (
    WorldInputs,
    WorldNoise,
    WorldParams,
    WorldState,
    broadcast,
    sense_world,
    step_world,
)

FloatArray = NDArray[np.float64]

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
    times_s = 2.0 * gaps_m / SPEED_OF_SOUND_MPS
    heard = np.isfinite(times_s)
    return [
        tuple(float(t) if h else None for t, h in zip(row, heard_row, strict=True))
        for row, heard_row in zip(times_s, heard, strict=True)
    ]


class WorldEngine:
    """Ground truth, sensors and radio of one scenario's robots."""

    def __init__(self, scenario: Scenario, seed: int | None = None) -> None:
        self.scenario = scenario
        self.names = scenario.robot_names
        self.robot_count = len(self.names)
        self.rng = np.random.default_rng(scenario.seed if seed is None else seed)
        self.noise = WorldNoise.spawn(self.rng)
        self.params = WorldParams.from_scenario(scenario)
        self.state = WorldState.at_rest(scenario.initial_poses())
        self.t_ns = 0
        self.radio = RadioCounters()
        self._queue: list[_Frame] = []
        self._order = 0
        self.fix_period_ns = round(NS_PER_S / self.params.positioning.rate_hz)
        self.sonar_period_ns = round(NS_PER_S / self.params.sonar.rate_hz)
        self.metrics_period_ns = round(scenario.controller_params().control_period_s * NS_PER_S)
        self._next_fix_ns = 0
        self._next_sonar_ns = 0
        self._sonar_echo_times_s = echo_times_from_gaps(
            np.full((self.robot_count, len(self.params.beam_angles_rad)), np.inf)
        )
        self._next_metrics_ns = 0
        self.trajectory = scenario.trajectory.build()
        self.metrics = MetricsAccumulator(
            (),
            FormationLayout.from_scenario(scenario),
            self.params.obstacle_centres_m,
            self.params.obstacle_radii_m,
            scenario.metrics_config(),
        )
        self.fixes_cut = np.zeros(self.robot_count, dtype=bool)

    @property
    def t_s(self) -> float:
        return self.t_ns / NS_PER_S

    @property
    def bodies(self) -> BodyState:
        return self.state.bodies

    @property
    def link(self) -> LinkProfile:
        """How the radio medium treats every link; can be changed while the world runs."""
        return self.params.link

    @link.setter
    def link(self, profile: LinkProfile) -> None:
        self.params = replace(self.params, link=profile)

    def sense(self) -> list[SenseMessage]:
        """What every robot's pins see now; fixes and sonar refresh at their own rates."""
        sonar_due = self.t_ns >= self._next_sonar_ns
        if sonar_due:
            self._next_sonar_ns += self.sonar_period_ns
        fix_due = self.t_ns >= self._next_fix_ns
        if fix_due:
            self._next_fix_ns += self.fix_period_ns
        seen = sense_world(self.state, self.params, self.noise, fix_due, sonar_due)
        if seen.sonar_gap_m is not None:
            self._sonar_echo_times_s = echo_times_from_gaps(seen.sonar_gap_m)
        fixes: list[FixSample | None] = [None] * self.robot_count
        if seen.fix_pose is not None:
            fixes = [
                FixSample(float(p[0]), float(p[1]), float(p[2]), self.t_ns, valid=not bool(cut))
                for p, cut in zip(seen.fix_pose, self.fixes_cut, strict=True)
            ]
        return [
            SenseMessage(
                encoder_counts=tuple(int(c) for c in counts),
                sonar_echo_times_s=echo,
                fix=fix,
                t_ns=self.t_ns,
            )
            for counts, echo, fix in zip(
                seen.encoder_counts, self._sonar_echo_times_s, fixes, strict=True
            )
        ]

    def advance(self, duty: FloatArray, dt_ns: int) -> None:
        """Step the bodies by dt_ns with the given duties (N, 4); record metrics on schedule."""
        if self.t_ns >= self._next_metrics_ns:
            self._next_metrics_ns += self.metrics_period_ns
            reference, _ = self.trajectory.evaluate(self.t_s)
            self.metrics.update(self.t_s, self.bodies.pose, reference, self.state.contacts)
        inputs = WorldInputs(duty=np.asarray(duty, dtype=np.float64), dt_s=dt_ns / NS_PER_S)
        self.state, _ = step_world(self.state, inputs, self.params, self.noise)
        self.t_ns += dt_ns

    def transmit(self, sender: int, payload: bytes) -> None:
        """A robot broadcasts `payload` now; each other robot gets it after its link's delay."""
        self.radio.sent += 1
        self.state, fates = broadcast(
            self.state, np.array([sender], dtype=np.int64), self.params, self.noise
        )
        for receiver in range(self.robot_count):
            if receiver == sender:
                continue
            if not fates.delivered[0, receiver]:
                self.radio.dropped += 1
                continue
            self._order += 1
            heapq.heappush(
                self._queue,
                _Frame(
                    arrival_ns=self.t_ns + round(float(fates.delay_s[0, receiver]) * NS_PER_S),
                    order=self._order,
                    receiver=receiver,
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

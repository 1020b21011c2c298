"""The world of a live swarm: bodies, sensor synthesis and the radio medium, stepped in time.

The world process (and in-process tests that run real firmware on real fabric models) drive a
`WorldEngine`: it owns the ground truth of every robot body, turns it into what each robot's
pins see (`SenseMessage`: running encoder counts, sonar echo times, positioning fixes) and takes
back what the motor pins carry (PWM duty per wheel).  It is also the radio medium: frames are
opaque bytes, delivered to every other robot after the link's delay, or dropped.

The engine is the stateful shell around the batched world step of `world.step` with an empty
batch shape: `sense` is `sense_world`, `advance` is `step_world` with no senders (in its
one-world form, `move_world`), and `transmit` is the step's radio half (`broadcast`) for one
sender, because frames reach the world whenever a robot sends one.  The batch simulator calls
the same functions, so a live run and `swarm sim` share physics, sensors, radio draws and noise
streams, and the metrics are the same `MetricsAccumulator`.  Time advances only through
`advance(duty, dt_ns)`; randomness comes from a generator seeded by the scenario.

Network faults (per-link profiles, partitions; world/faults.py) are the engine's too: the radio
draws each frame from them while one is active (`apply_network_fault`).

`checkpoint_state` captures everything that decides what the engine does next (bodies, time,
the radio queue and burst states, every generator's state, the sensors' schedules, the metric
accumulators, the link profile and network faults, counters) and `restore_checkpoint` carries
on from it in a fresh engine, bit for bit (world/checkpoint.py writes it to disk).
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from robot_firmware.net.wire import SenseMessage, SensePins
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario
from world.checkpoint import CheckpointError, decode_array, encode_array
from world.faults import NetworkFault, NetworkFaults
from world.metrics import FormationLayout, MetricsAccumulator
from world.physics import BodyState
from world.radio import RowDraw
from world.step import (
    WorldNoise,
    WorldParams,
    WorldState,
    broadcast,
    move_world,
    sense_world,
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


def echo_times_from_gaps(gaps_m: FloatArray) -> FloatArray:
    """Round-trip echo time per robot and transducer for gaps (n, beams); NaN = no echo."""
    times_s = 2.0 * gaps_m / SPEED_OF_SOUND_MPS
    return np.where(np.isfinite(times_s), times_s, np.nan)


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
        self.collisions: list[tuple[float, str, str]] = []
        """Contacts that began, (t_s, robot, what it touched: a robot or `obstacle K`), in the
        order the metrics counted them; the world process drains them into its events."""
        self.fixes_cut = np.zeros(self.robot_count, dtype=bool)
        self.network = NetworkFaults(self.names)
        """The radio medium's network faults (world/faults.py); none at the start."""
        self._row_draw: RowDraw | None = None
        """The draw of one frame's links while they share the profile `link` (`transmit`)."""

    def compile_kernels(self) -> None:
        """Run the compiled kernels the engine steps with once each, on scratch copies: the
        first call of a kernel in a process compiles it, or loads it from numba's cache, and
        after an install or an edit of their sources compiling them takes seconds, which the
        world must spend before its clock starts, not at its first sense tick.  Nothing of the
        engine changes: not its state, time, noise streams, radio nor metrics."""
        scratch = WorldNoise.spawn(np.random.default_rng(0))
        state = self.state
        sense_world(state, self.params, scratch, fix_due=True, sonar_due=True)
        moved = move_world(state, np.zeros((self.robot_count, 4)), 1e-3, self.params, scratch)
        RowDraw(self.params.link, self.robot_count)(state.link_bad[0], scratch.radio)
        metrics = MetricsAccumulator(
            (),
            FormationLayout.from_scenario(self.scenario),
            self.params.obstacle_centres_m,
            self.params.obstacle_radii_m,
            self.scenario.metrics_config(),
        )
        reference, _ = self.trajectory.evaluate(0.0)
        for contacts in (None, moved.contacts):  # before the first step, and after it
            metrics.update(0.0, moved.bodies.pose, reference, contacts)

    @property
    def t_s(self) -> float:
        return self.t_ns / NS_PER_S

    @property
    def bodies(self) -> BodyState:
        return self.state.bodies

    @property
    def link(self) -> LinkProfile:
        """How the radio medium treats every link a network fault does not change; can be
        changed while the world runs."""
        return self.params.link

    @link.setter
    def link(self, profile: LinkProfile) -> None:
        self.params = replace(
            self.params, link=profile, link_table=self.network.link_table(profile)
        )

    def apply_network_fault(self, fault: NetworkFault) -> None:
        """Loss, delay, jitter or bursts on some links, a partition, or heal (world/faults.py);
        from the next frame on.  KeyError, changing nothing, for a robot outside the swarm."""
        self.network.apply(fault)
        self.params = replace(self.params, link_table=self.network.link_table(self.link))

    def sense(self) -> list[SenseMessage]:
        """What every robot's pins see now, one message per robot (`sense_pins`)."""
        return self.sense_pins().messages()

    def sense_pins(self) -> SensePins:
        """What every robot's pins see now, as arrays; fixes and sonar refresh at their own
        rates."""
        sonar_due = self.t_ns >= self._next_sonar_ns
        if sonar_due:
            self._next_sonar_ns += self.sonar_period_ns
        fix_due = self.t_ns >= self._next_fix_ns
        if fix_due:
            self._next_fix_ns += self.fix_period_ns
        seen = sense_world(self.state, self.params, self.noise, fix_due, sonar_due)
        if seen.sonar_gap_m is not None:
            self._sonar_echo_times_s = echo_times_from_gaps(seen.sonar_gap_m)
        return SensePins(
            encoder_counts=np.asarray(seen.encoder_counts, dtype=np.int64),
            echo_times_s=self._sonar_echo_times_s,
            fix_pose=None if seen.fix_pose is None else np.asarray(seen.fix_pose, np.float64),
            fix_valid=~self.fixes_cut,
            t_ns=self.t_ns,
        )

    def record_metrics(self) -> None:
        """Take the metrics sample due at the current time, if one is due and not yet taken.

        `advance` takes it itself before it steps; a caller may take it earlier, while the
        bodies are where they are now (the lockstep world does so while the robots compute)."""
        if self.t_ns >= self._next_metrics_ns:
            self._next_metrics_ns += self.metrics_period_ns
            reference, _ = self.trajectory.evaluate(self.t_s)
            self.metrics.update(self.t_s, self.bodies.pose, reference, self.state.contacts)
            for robot, other in self.metrics.last_onsets:
                with_ = (
                    self.names[other]
                    if other < self.robot_count
                    else f"obstacle {other - self.robot_count + 1}"
                )
                self.collisions.append((self.t_s, self.names[robot], with_))

    def advance(self, duty: FloatArray, dt_ns: int) -> None:
        """Step the bodies by dt_ns with the given duties (N, 4); record metrics on schedule."""
        self.record_metrics()
        self.state = move_world(self.state, duty, dt_ns / NS_PER_S, self.params, self.noise)
        self.t_ns += dt_ns

    def transmit(self, sender: int, payload: bytes, sent_ns: int | None = None) -> None:
        """A robot broadcasts `payload` at simulation time `sent_ns` (default: the engine's
        time); each other robot gets it after its link's delay.  The real-time world sends at
        its clock, which runs ahead of the physics between the steps it takes.

        With one profile for every link and no range (no network fault: the common case) the
        links are drawn by `RowDraw`, which gives `broadcast`'s fates with a fraction of its
        Python; otherwise by `broadcast` itself."""
        self.radio.sent += 1
        params = self.params
        if params.link_table is None and params.link.range_m is None:
            row = self._row_draw
            if row is None or row.profile is not params.link:
                row = self._row_draw = RowDraw(params.link, self.robot_count)
            delivered, delays_s, bad = row(self.state.link_bad[sender], self.noise.radio)
            if row.burst:
                link_bad = self.state.link_bad.copy()
                link_bad[sender] = bad
                self.state = replace(self.state, link_bad=link_bad)
        else:
            self.state, fates = broadcast(
                self.state, np.array([sender], dtype=np.int64), params, self.noise
            )
            delivered, delays_s = fates.delivered[0], fates.delay_s[0]
        sent_ns = self.t_ns if sent_ns is None else sent_ns
        for receiver in range(self.robot_count):
            if receiver == sender:
                continue
            if not delivered[receiver]:
                self.radio.dropped += 1
                continue
            self._order += 1
            heapq.heappush(
                self._queue,
                _Frame(
                    arrival_ns=sent_ns + round(float(delays_s[receiver]) * NS_PER_S),
                    order=self._order,
                    receiver=receiver,
                    sender=sender,
                    sent_ns=sent_ns,
                    payload=payload,
                ),
            )

    def next_frame_due_ns(self) -> int | None:
        """When the next queued frame arrives (simulation ns), or None."""
        return self._queue[0].arrival_ns if self._queue else None

    def due_frames(self, until_ns: int | None = None) -> list[tuple[int, int, bytes]]:
        """Frames that have arrived by simulation time `until_ns` (default: the engine's
        time), as (receiver, sender, payload), oldest first."""
        until_ns = self.t_ns if until_ns is None else until_ns
        out = []
        while self._queue and self._queue[0].arrival_ns <= until_ns:
            frame = heapq.heappop(self._queue)
            self.radio.delivered += 1
            self.radio.latencies_ns.append(frame.arrival_ns - frame.sent_ns)
            out.append((frame.receiver, frame.sender, frame.payload))
        return out

    def summary(self) -> dict[str, object]:
        return self.metrics.summaries()[0]

    # -- checkpoints (world/checkpoint.py) -------------------------------------------------

    def _generators(self) -> dict[str, np.random.Generator]:
        noise = self.noise
        return {
            "root": self.rng,
            "fix": noise.fix,
            "sonar": noise.sonar,
            "radio": noise.radio,
            "slip": noise.slip,
        }

    def checkpoint_state(self) -> dict[str, object]:
        """Everything that decides what this engine does next, as JSON-able values: restoring
        it in a fresh engine of the same scenario continues this run bit for bit."""
        bodies = self.state.bodies
        contacts = self.state.contacts
        echoes = np.array(self._sonar_echo_times_s, dtype=np.float64)
        metrics = {
            name: encode_array(value) if isinstance(value, np.ndarray) else value
            for name, value in self.metrics.export_state().items()
        }
        return {
            "scenario": self.scenario.name,
            "robots": list(self.names),
            "t_ns": self.t_ns,
            "bodies": {
                "pose": encode_array(bodies.pose),
                "wheel_speed_radps": encode_array(bodies.wheel_speed_radps),
                "wheel_angle_rad": encode_array(bodies.wheel_angle_rad),
                "slip": encode_array(bodies.slip),
            },
            "link_bad": encode_array(self.state.link_bad),
            "contacts": None if contacts is None else encode_array(contacts),
            "rng": {name: g.bit_generator.state for name, g in self._generators().items()},
            "radio": {
                "sent": self.radio.sent,
                "delivered": self.radio.delivered,
                "dropped": self.radio.dropped,
                "latencies_ns": encode_array(
                    np.fromiter(
                        self.radio.latencies_ns, dtype=np.int64, count=len(self.radio.latencies_ns)
                    )
                ),
            },
            "queue": [
                [f.arrival_ns, f.order, f.receiver, f.sender, f.sent_ns, f.payload.hex()]
                for f in self._queue
            ],
            "order": self._order,
            "next_fix_ns": self._next_fix_ns,
            "next_sonar_ns": self._next_sonar_ns,
            "next_metrics_ns": self._next_metrics_ns,
            "sonar_echo_times_s": encode_array(echoes),
            "fixes_cut": encode_array(self.fixes_cut),
            "link": self.link.model_dump(mode="json", exclude_none=True),
            "network": self.network.export_state(),
            "metrics": metrics,
        }

    def restore_checkpoint(self, state: Mapping[str, Any]) -> None:
        """Carry on from `checkpoint_state`; a state of another scenario, or one that does not
        fit this engine, raises CheckpointError and changes nothing."""
        try:
            restored = self._restored(state)
        except CheckpointError:
            raise
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise CheckpointError(f"the state does not fit this world: {exc!r}") from None
        for name, value in restored.items():
            setattr(self, name, value)

    def _restored(self, state: Mapping[str, Any]) -> dict[str, object]:
        """The attributes `state` sets, checked against this engine; nothing is changed."""
        if state["scenario"] != self.scenario.name or tuple(state["robots"]) != self.names:
            raise CheckpointError(
                f"a checkpoint of scenario {state['scenario']!r} with robots {state['robots']}, "
                f"not of {self.scenario.name!r} with {list(self.names)}"
            )
        n = self.robot_count
        b = state["bodies"]
        bodies = BodyState(
            pose=decode_array(b["pose"]),
            wheel_speed_radps=decode_array(b["wheel_speed_radps"]),
            wheel_angle_rad=decode_array(b["wheel_angle_rad"]),
            slip=decode_array(b["slip"]),
        )
        shapes = (bodies.pose.shape, bodies.wheel_speed_radps.shape, bodies.slip.shape)
        if shapes != ((n, 3), (n, 4), (n, 4)) or bodies.wheel_angle_rad.shape != (n, 4):
            raise CheckpointError(f"body arrays of shapes {shapes} for {n} robots")
        link_bad = decode_array(state["link_bad"]).astype(bool)
        contacts = None if state["contacts"] is None else decode_array(state["contacts"])
        generators = {}
        for name, current in self._generators().items():
            fresh = np.random.Generator(type(current.bit_generator)())
            fresh.bit_generator.state = state["rng"][name]
            generators[name] = fresh
        noise = WorldNoise(
            fix=generators["fix"],
            sonar=generators["sonar"],
            radio=generators["radio"],
            slip=generators["slip"],
        )
        r = state["radio"]
        radio = RadioCounters(
            sent=int(r["sent"]), delivered=int(r["delivered"]), dropped=int(r["dropped"])
        )
        radio.latencies_ns.extend(int(v) for v in decode_array(r["latencies_ns"]))
        frames = [
            _Frame(int(a), int(o), int(rc), int(sd), int(sn), bytes.fromhex(p))
            for a, o, rc, sd, sn, p in state["queue"]
        ]
        echoes = decode_array(state["sonar_echo_times_s"])
        metrics = {
            name: decode_array(value) if isinstance(value, dict) else value
            for name, value in state["metrics"].items()
        }
        accumulator = MetricsAccumulator(
            (),
            self.metrics.layout,
            self.metrics.obstacle_centres_m,
            self.metrics.obstacle_radii_m,
            self.metrics.config,
        )
        accumulator.import_state(metrics)
        link = LinkProfile.model_validate(state["link"])
        # A checkpoint from before network faults existed has none.
        network = (
            NetworkFaults(self.names)
            if state.get("network") is None
            else self.network.restored(state["network"])
        )
        return {
            "t_ns": int(state["t_ns"]),
            "state": WorldState(bodies=bodies, link_bad=link_bad, contacts=contacts),
            "rng": generators["root"],
            "noise": noise,
            "radio": radio,
            "_queue": frames,
            "_order": int(state["order"]),
            "_next_fix_ns": int(state["next_fix_ns"]),
            "_next_sonar_ns": int(state["next_sonar_ns"]),
            "_next_metrics_ns": int(state["next_metrics_ns"]),
            "_sonar_echo_times_s": np.asarray(echoes, dtype=np.float64),
            "fixes_cut": decode_array(state["fixes_cut"]).astype(bool),
            "params": replace(self.params, link=link, link_table=network.link_table(link)),
            "network": network,
            "metrics": accumulator,
        }

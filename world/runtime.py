"""The world process: physics, sensors and the radio medium of a swarm, served over Zenoh.

It owns a `WorldEngine` and talks to the robots only through their pins and the radio:
publishes `wire/<robot>/sense`, reads `wire/<robot>/act`, forwards `radio/tx/<robot>` frames to
the other robots' `radio/rx/<robot>` after the link profile's delay (or drops them; the frames
one pass of the medium has for a robot go in one bundle, robot_firmware/net/radio_bundle.py),
and publishes ground truth and metrics on `truth`.  Zenoh callbacks only queue what arrives; in
real time a relay thread of the radio medium passes frames on as they come (`_relay_frames`),
touching the engine only under the lock the main loop holds while it is awake.

Clock modes:
* real time (default): simulation time is wall time, except that the starvation guard
  (world/realtime_guard.py) holds it back so that it never runs more than two control periods
  (`starvation_lead_periods`) beyond the period the slowest live robot has answered (its act
  messages carry the tick of the newest sense message it had), nor beyond the newest sense tick
  the world itself has published: a starved host slows the run down (real-time factor < 1)
  instead of letting robots drive blind or the world's clock run away from the sense ticks it
  owes, and a frozen robot holds it for at most `starvation_hold_limit_s`.  The physics is
  integrated exactly from event to event (duty change at the first `act_grid_ms` step after an
  act's arrival, frame due, sense due; an act is applied at the loop's next pass and wakes it
  only while the time is held), sense messages go out every control period (repeated, with no
  new fix, while the time is held); a body whose last act message is older than
  `act_timeout_ms` of simulated time, or that the guard stopped waiting for, is braked;
* lockstep: per control period the world sends every robot its sense message with the tick
  number and waits until every *live* robot (liveliness token present) has answered that tick,
  then advances the physics by one period.  A robot that disappears leaves the barrier at once
  and is braked; one that comes back is waited for again from its next answer on.  With
  `max_speed` set, a tick is not started before its simulated time divided by `max_speed` has
  passed on the wall clock (a deterministic run slowed down to watch; results unchanged).

With an output directory the world checkpoints its whole state (engine, lockstep bookkeeping,
counters) every `checkpoint_every_s` simulated seconds (at most 1) into `<out>/checkpoints/`,
encoded and written on a thread of its own, durably and atomically (world/checkpoint.py); a
world started on a directory that holds one resumes from the newest valid checkpoint instead of
t = 0.
Every start of the world has a new random epoch on its clock and sense messages, so the
robots know when the clock jumped (robot_firmware/tick_scheduler.py).

Who leads (for the metrics, DESIGN.md §8) the world learns from the robots' telemetry: each
reports its acting role and leader term (robot_firmware/leadership.py).  The world reads no
robot internals and the radio frames are opaque to it; liveliness would say who is up, not who
leads (a restarted old leader is up and follows).  The acting leader is the live robot that
reports leading with the highest term (ties: lower index); until another reports, the last one
stays.  A change is recorded at the reporting robot's own simulation time (`set_leader`, and a
`leader_change` event), so the event's time does not depend on delivery.  In real time the
samples between that time and the telemetry's arrival (at most a telemetry period late) are
still taken against the old leader; in lockstep telemetry stamped t is applied at the tick
boundary t + `TELEMETRY_DELAY_PERIODS` control periods, after the world has waited for what each
robot owes by then (world/faults.py `TelemetryGate`), so the metrics change leader at a
deterministic tick and a replay gives the same summary.json.

The world is the swarm's one fault entry point (world/faults.py).  Faults take effect at a tick
boundary, before the tick's sense messages go out (in lockstep while the world holds the tick):
the scenario's `faults:` campaign at the first tick at or after each entry's time, and the
requests of the admin verb `admin/world/fault`, whose queries are held until the next
boundary.  Network faults change the radio medium (per-link profiles, partitions); register
faults are forwarded to the robot's `fault` verb; process faults to the launcher's verbs.
Every fault, refused or injected, and every consequence (a robot down or up at the barrier's
leave or join tick, a leader change, this world resumed from a checkpoint) is a `RunEvent`:
appended durably to `<out>/events.jsonl`, published on `swarm/<swarm>/events`, and summed up
in summary.json's `run_events`.  The campaign's cursor and the count of events are part of the
checkpoint; a resumed world cuts events.jsonl back to that count.  Joins and leaves before time
starts are the swarm booting, not events.

At the end (duration reached, SIGTERM or Ctrl-C) and every few seconds meanwhile the world
writes `summary.json` with the schema of `swarm sim`, plus radio counters and the robots'
control-loop timing, atomically.  Admin queryables: `admin/world/status`, `admin/world/net`
(get the link profile, or set it with a JSON body; an invalid one is refused and changes
nothing), `admin/world/fault` (one fault of swarm_config/faults.py -> `FaultReply`).
"""

from __future__ import annotations

import gc
import json
import logging
import queue
import secrets
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import zenoh
from pydantic import (
    ConfigDict,
    Field,
    FilePath,
    PositiveFloat,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from robot_firmware.net.admin import AdminQueue, Handler
from robot_firmware.net.answers import PendingAnswer
from robot_firmware.net.frames import claimed_sender
from robot_firmware.net.keys import SwarmKeys, check_name
from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    LockstepProfileReport,
    LockstepSeat,
    LoopTimingReport,
    NetProfileRequest,
    NetReply,
    RadioStats,
    RefusedInput,
    RobotTruth,
    RunMetrics,
    TelemetryMessage,
    TruthMessage,
    WorldStatusReply,
    parse_message,
)
from robot_firmware.net.radio_bundle import bundle_frames
from robot_firmware.net.request_deadline import request_attachment
from robot_firmware.net.session import (
    DEFAULT_ENDPOINT,
    open_client_until_stopped,
    split_endpoints,
)
from robot_firmware.net.wire import (
    ActMessage,
    ClockMessage,
    SensePins,
    WireCounters,
    WireDropReason,
    encode_clock,
    encode_sense_rows,
    parse_act,
)
from swarm_config.credentials import (
    CREDENTIALS_FILE_ENV,
    WORLD,
    OptionalCredentialsFile,
    check_identity,
)
from swarm_config.faults import EventKind, RunEvent
from swarm_config.radio import PROFILES, LinkProfile
from swarm_config.scenario import DEFAULT_SCENARIO_PATH, Scenario, load_rule_base
from swarm_config.settings import Endpoints, LayeredSettings, describe_validation_error
from world.checkpoint import (
    CHECKPOINT_DIR_NAME,
    CheckpointError,
    CheckpointStore,
    CheckpointWriter,
    LoadedCheckpoint,
)
from world.engine import NS_PER_S, WorldEngine
from world.faults import (
    EVENTS_FILE_NAME,
    EventLog,
    FaultHub,
    FaultSchedule,
    NetworkFault,
    TelemetryGate,
)
from world.input_budget import PER_PERIOD, InputBudget
from world.lockstep import LockstepBarrier, LockstepPacer, LockstepProfile
from world.metrics import FormationLayout, reference_points, sample_errors
from world.realtime_guard import LEAD_PERIODS, RealTimeGuard, SenseLateness
from world.summary import build_summary, summarise_events, write_json_atomically
from world.write_failures import EXIT_SUMMARY_NOT_WRITTEN, WriteFailures

log = logging.getLogger("swarm.world")

MAX_PHYSICS_STEP_NS = 10_000_000
"""Longest exact physics step; contacts are resolved at least this often."""
INPUT_KINDS = {"act": "act messages", "frame": "radio frames", "telemetry": "telemetry samples"}
"""The messages a robot puts on its own keys, each kind with its own budget."""
ACTS_NEVER_WAKE = 1 << 30
"""A queue length no act count reaches: the real-time world's act threshold."""
TELEMETRY_DELAY_PERIODS = 2
"""Lockstep: a telemetry sample stamped t is applied at the tick boundary t + this many
control periods (world/faults.py `TelemetryGate`)."""
DEFAULT_TELEMETRY_INTERVAL_S = 0.05
"""A robot's telemetry period until two samples tell its own (robot_firmware/runtime.py)."""
TELEMETRY_WAIT_S = 2.0
"""Lockstep: how long a tick boundary waits for a robot's expected telemetry before it stops
waiting for that robot (until it speaks again)."""
PEER_TOKEN_GRACE_S = 0.3
"""Lockstep: after a token change the world itself waited for, how much longer it holds the
tick, so that every robot has heard of it before the next one (robots act on peers' tokens)."""
ANSWER_WAIT_STEP_NS = 100_000_000
"""Lockstep: the most one pass of the wait for answers adds to the answer time-out (0.1 s;
a pass waits at most 0.05 s unless the process was frozen)."""


def act_effect_ns(arrival_ns: int, limit_ns: int, grid_ns: int) -> int:
    """Real time: the simulated instant an act that came at `arrival_ns` changes its duty:
    the first multiple of `grid_ns` at or after it (`arrival_ns` itself for a grid of 0), but
    not after `limit_ns` (the loop's clock, or the next sense tick if that is sooner) unless
    the act itself came after it."""
    if grid_ns <= 0:
        return arrival_ns
    return min(-(-arrival_ns // grid_ns) * grid_ns, max(arrival_ns, limit_ns))


class WorldConfig(LayeredSettings):
    """Settings of the world process: YAML file (`swarm world --config`), then environment,
    then flags."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    swarm: str = "lab"
    scenario: Path = DEFAULT_SCENARIO_PATH
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT], min_length=1)
    zenoh_config: FilePath | None = None
    lockstep: bool = False
    duration_s: PositiveFloat | None = None
    out_dir: Path | None = None
    act_timeout_ms: PositiveFloat = 100.0
    truth_rate_hz: PositiveFloat = 20.0
    summary_every_s: PositiveFloat = 5.0
    radio_profile: str | None = None
    start_timeout_s: PositiveFloat = 30.0
    checkpoint_every_s: float = Field(default=0.5, gt=0.0, le=1.0)
    """Simulated seconds between checkpoints in `<out_dir>/checkpoints/` (at most 1)."""
    max_speed: PositiveFloat | None = None
    """Lockstep only: at most this many simulated seconds per wall second (None: as fast as
    the robots answer)."""
    starvation_guard: bool = True
    """Real time: simulated time never runs more than `starvation_lead_periods` control periods
    beyond the period the slowest live robot has answered; the run slows down instead
    (world/realtime_guard.py).
    Off: simulated time is the wall clock, whatever the robots do."""
    lockstep_token_grace_s: PositiveFloat = 5.0
    """Lockstep: how long (wall time) the world waits for a robot whose liveliness token went,
    holding the tick, before it takes the robot as down at that tick.  A router that restarts
    takes every token with it and brings them back as the clients reconnect: no robot is down,
    and no simulated time passes meanwhile."""
    lockstep_answer_timeout_s: PositiveFloat = 2.0
    """Lockstep: how long (wall time) a tick waits for a live robot's answer before it goes
    on without it and waits for it again from the next tick (a message to or from it was lost,
    world/lockstep.py "Lost messages").  No answer of a run without lost messages comes this
    late, so such a run replays exactly."""
    starvation_lead_periods: int = Field(default=LEAD_PERIODS, ge=0, le=10)
    """Real time: how many control periods simulated time may run beyond the period the
    slowest robot has answered (world/realtime_guard.py, "The rule")."""
    starvation_hold_limit_s: float = Field(default=0.5, gt=0.0, le=1.0)
    """Real time: the longest the world waits for one robot before it goes on without it
    (braking its body): at most the robots' liveliness lease (1 s)."""
    act_grid_ms: float = Field(default=1.0, ge=0.0, le=5.0)
    """Real time: an act's duty takes effect at the first multiple of this much simulated time
    at or after the act came, as in a physics loop of that step, so the acts that come within
    one step share a physics step; 0: at the very instant it came, one physics step per act.
    Lockstep applies every act at its tick anyway."""
    credentials: OptionalCredentialsFile = Field(default=None, repr=False)
    """The world's router user and password (swarm_config/credentials.py), from the file
    named by --credentials or $SWARM_CREDENTIALS_FILE; `swarm world` refuses to start
    without them."""

    WHAT: ClassVar[str] = "world settings"
    ENV: ClassVar[Mapping[str, str]] = {
        "swarm": "SWARM_NAME",
        "scenario": "SWARM_SCENARIO",
        "connect": "ZENOH_CONNECT",
        "zenoh_config": "ZENOH_CONFIG",
        "radio_profile": "SWARM_RADIO_PROFILE",
        "credentials": CREDENTIALS_FILE_ENV,
        "starvation_guard": "SWARM_STARVATION_GUARD",
    }
    ENV_PARSERS: ClassVar[Mapping[str, Callable[[str], object]]] = {"connect": split_endpoints}

    @field_validator("swarm")
    @classmethod
    def _key_chunk(cls, value: str) -> str:
        return check_name("swarm", value)

    @field_validator("radio_profile")
    @classmethod
    def _known_profile(cls, value: str | None) -> str | None:
        if value is not None and value not in PROFILES:
            raise ValueError(
                f"unknown radio profile {value!r}; known: {', '.join(sorted(PROFILES))}"
            )
        return value

    @field_validator("max_speed")
    @classmethod
    def _max_speed_needs_lockstep(cls, value: float | None, info: ValidationInfo) -> float | None:
        if value is not None and not info.data.get("lockstep", False):
            raise ValueError("applies to lockstep runs only (real time runs at 1)")
        return value

    @model_validator(mode="after")
    def _credentials_are_the_worlds(self) -> WorldConfig:
        if self.credentials is not None:
            check_identity(self.credentials, WORLD, self.swarm)
        return self

    def scenario_problem(self, scenario: Scenario) -> str | None:
        """What these settings cannot do with `scenario`, for a usage error, or None: a run
        shorter than one control period would end before its first tick."""
        period_s = scenario.controller_params().control_period_s
        if self.duration_s is not None and self.duration_s < period_s:
            return (
                f"duration_s (--duration): {self.duration_s:g} s is shorter than one control "
                f"period of scenario {scenario.name!r} ({period_s:g} s): nothing would run"
            )
        return None


def new_epoch(avoid: object = None) -> int:
    """A random non-zero u32 naming one start of the world, never `avoid` (the epoch of the
    checkpoint it resumes from); 0 is what a message without one would say."""
    while True:
        epoch = secrets.randbits(32)
        if epoch not in (0, avoid):
            return epoch


def _overloaded_on_purpose(telemetry: TelemetryMessage) -> bool:
    """Whether the robot reports a `tick_slow` register fault (a deliberate CPU overload)."""
    return any(label.split("(", 1)[0] == "tick_slow" for label in telemetry.register_faults)


SEND_TIMEOUT_S = 5.0
"""How long a request the world does not wait for (its own and the router's kill, restart or
stop, which the launcher carries out) stays good for."""


def _take_answer(pending: PendingAnswer, reply: zenoh.Reply) -> None:
    """A zenoh callback: a good answer into `pending`."""
    if reply.ok is not None:
        pending.on_answer(bytes(reply.ok.payload.to_bytes()))


def _ignore_reply(_reply: zenoh.Reply) -> None:
    """The callback of a request whose answer nobody waits for."""


class WorldProcess:
    def __init__(self, config: WorldConfig, scenario: Scenario) -> None:
        if config.radio_profile is not None:
            radio = scenario.radio.model_copy(update={"profile": config.radio_profile})
            scenario = scenario.model_copy(update={"radio": radio})
        self.config = config
        self.scenario = scenario
        self.engine = WorldEngine(scenario)
        self.keys = SwarmKeys(config.swarm)
        self.names = scenario.robot_names
        self.index = {name: i for i, name in enumerate(self.names)}
        self.period_ns = round(scenario.controller_params().control_period_s * NS_PER_S)
        self.duty = np.zeros((len(self.names), 4))
        self.act_seen_mono_ns = np.full(len(self.names), -(10**18), dtype=np.int64)
        self.act_seen_sim_ns = np.full(len(self.names), -(10**18), dtype=np.int64)
        """Simulation time at which each robot's newest act message was applied."""
        self.barrier = LockstepBarrier(self.names)
        self.lockstep_profile = LockstepProfile()
        """Lockstep: where the ticks' wall time goes (observed only, world/lockstep.py)."""
        self.guard = RealTimeGuard(
            self.names,
            self.period_ns,
            round(config.starvation_hold_limit_s * NS_PER_S),
            lead_periods=config.starvation_lead_periods,
            enabled=config.starvation_guard and not config.lockstep,
        )
        """Real time: holds simulated time back for starved robots (world/realtime_guard.py)."""
        self.sense_lateness = SenseLateness(self.period_ns)
        """Real time: how late the loop's own work made each sense tick."""
        self._act_grid_ns = round(config.act_grid_ms * 1e6)
        """Real time: the step of simulated time on which acts change duties (`act_effect_ns`)."""
        self._sense_sent: tuple[SensePins, int] | None = None
        self._sense_sent_mono_ns = 0
        self._sense_out_mono_ns = 0
        """When the first of the newest sense messages went out."""
        """The newest sense messages and when they went out (repeated while time is held)."""
        self._acts: queue.SimpleQueue[tuple[str, bytes, int]] = queue.SimpleQueue()
        self._frames: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        """Frames as they come, (sender, payload): taken at the barrier in lockstep; in real
        time passed on under the engine's lock (`_pass_frames_on`)."""
        self._frames_queued = threading.Event()
        """Real time: set by the frames' callback, cleared by the radio relay under the lock."""
        self._relay_stopping = False
        self._liveliness: queue.SimpleQueue[tuple[str, bool]] = queue.SimpleQueue()
        self._token_lost_mono_s: dict[str, float] = {}
        """Lockstep: live robots whose token went, and when (monotonic s): held for the grace
        (`lockstep_token_grace_s`) before they are down."""
        self._tokens_up: set[str] = set()
        """The robots whose liveliness token the world has seen and not seen go."""
        self._telemetry: queue.SimpleQueue[TelemetryMessage] = queue.SimpleQueue()
        self._admin = AdminQueue()
        self._fault_admin = AdminQueue()
        """Queries of the `fault` verb: served only at a tick boundary."""
        self._wake = threading.Event()
        self._acts_wake_at = 1 if config.lockstep else ACTS_NEVER_WAKE
        self._frames_wake_at = 1
        """The callbacks wake the main loop once this many acts (frames) are queued: in
        lockstep, what the tick still waits for (`_await_answers`), else every one.  In real
        time an act wakes it only while the starvation guard holds the time (`_run_realtime`
        says why)."""
        self._telemetry_wanted = False
        """Lockstep: a tick boundary waits for telemetry (its callback wakes the loop)."""
        self.stop = threading.Event()
        self.act_counters = WireCounters()
        """Act messages applied, and refused per `WireDropReason`."""
        self.malformed_telemetry = 0
        """Telemetry refused in the subscriber's callback (`_on_telemetry`)."""
        self.telemetry_ahead = 0
        """Lockstep telemetry stamped ahead of the world's clock, refused by the main loop
        (`_take_telemetry`); reported within `malformed_telemetry`."""
        self._warned_ahead: set[str] = set()
        self.budgets = {kind: InputBudget(self.names, self.period_ns) for kind in INPUT_KINDS}
        """Per kind of message a robot puts: how many it may (world/input_budget.py)."""
        self._warned_budget: set[tuple[str, str]] = set()
        self.unknown_senders = 0
        self.spoofed_frames = 0
        """Frames from robotN's transmitter that claim another sender id (dropped)."""
        self._catch_up: Callable[[int, int], None] | None = None
        self._held_frames: list[tuple[int, bytes]] = []
        self._engine_lock = threading.Lock()
        """Real time: held by the main loop while it is awake and by the radio relay while it
        passes frames on (`_relay_frames`); everything the engine holds is touched under it."""
        self.timing: dict[str, LoopTimingReport] = {}
        self.sense_drops: dict[str, dict[str, int]] = {}
        self.reported_roles: dict[str, tuple[bool, int, float]] = {}
        """Each robot's latest telemetry: whether it leads, its term, its time (s)."""
        self.telemetry_gate: TelemetryGate[TelemetryMessage] = TelemetryGate(
            self.names,
            delay_ns=TELEMETRY_DELAY_PERIODS * self.period_ns if config.lockstep else 0,
            default_interval_ns=round(DEFAULT_TELEMETRY_INTERVAL_S * NS_PER_S),
            max_ahead_ns=self.period_ns if config.lockstep else None,
        )
        """When each robot's telemetry is applied (module docstring)."""
        self.schedule = FaultSchedule(scenario.faults)
        """The scenario's fault campaign and its cursor."""
        self.event_log = EventLog(
            None if config.out_dir is None else config.out_dir / EVENTS_FILE_NAME
        )
        self.faults = FaultHub(self.names, self)
        self._session: zenoh.Session | None = None
        self._events_pub: zenoh.Publisher | None = None
        self._unpublished: list[RunEvent] = []
        self._time_started = False
        """Joins and leaves before time starts are the swarm booting, not events."""
        self._checkpoint_event_count = 0
        self._sense_publishers: list[zenoh.Publisher] = []
        """`wire/<robot>/sense` per robot index."""
        self._rx_publishers: list[zenoh.Publisher] = []
        """`radio/rx/<robot>` per robot index."""
        self._clock_started_mono_s: float | None = None
        self.rule_count_total = int(np.asarray(load_rule_base(scenario).rule_count)) * len(
            self.names
        )
        self._clock_started_sim_ns = 0
        self.next_sense_ns = 0
        """Real time: when the next sense message is due (simulation ns)."""
        self.checkpoint_period_ns = round(config.checkpoint_every_s * NS_PER_S)
        self._next_checkpoint_ns = self.checkpoint_period_ns
        self.checkpoints = (
            None
            if config.out_dir is None
            else CheckpointStore(config.out_dir / CHECKPOINT_DIR_NAME)
        )
        self._checkpoint_writer: CheckpointWriter | None = None
        self.checkpoint_failures = WriteFailures(
            "checkpoint", logging.getLogger("swarm.world.checkpoint")
        )
        self.summary_failures = WriteFailures("summary.json", log)
        self.resumed_from: LoadedCheckpoint | None = None
        self.resumes: list[dict[str, float | int]] = []
        """Each restart of this run's world from a checkpoint: its time and tick."""
        self.epoch = new_epoch()
        """This start of the world, on every clock and sense message (DESIGN.md §7.1)."""
        self.run_id = None if config.credentials is None else config.credentials.run_id
        """The run this world belongs to (its credentials'; a new one for every `swarm up`, or
        `docker compose up`): it resumes only from its own run's checkpoints."""
        if self.checkpoints is not None:
            if self.run_id is not None and (gone := self.checkpoints.clear_other_runs(self.run_id)):
                log.info("%d checkpoints of an earlier run removed: this is a new run", gone)
            self.resumed_from = self.checkpoints.load_latest(self.restore_checkpoint)
            if self.resumed_from is not None:
                log.info(
                    "resuming from checkpoint %s: tick %d, t = %.3f s",
                    self.resumed_from.path.name,
                    self.tick,
                    self.engine.t_s,
                )
        # events.jsonl: what the checkpoint had seen, or nothing for a fresh run.
        resumed = self.resumed_from is not None
        self.event_log.start(self._checkpoint_event_count if resumed else None)
        if resumed:
            self.record("world_resumed", None, {"tick": self.tick})

    # -- checkpoints -----------------------------------------------------------------------

    def checkpoint_state(self) -> dict[str, object]:
        """The engine's state, the lockstep bookkeeping and the world's own counters."""
        return {
            "run_id": self.run_id,
            "engine": self.engine.checkpoint_state(),
            "lockstep": self.barrier.export_state(),
            "epoch": self.epoch,
            "resumes": list(self.resumes),
            "next_sense_ns": self.next_sense_ns,
            "faults": {"cursor": self.schedule.cursor, "events": self.event_log.count},
            "counters": {
                "acts_accepted": self.act_counters.accepted,
                "acts_dropped": self.act_counters.dropped_as_dict(),
                "malformed_telemetry": self.malformed_telemetry + self.telemetry_ahead,
                "unknown_senders": self.unknown_senders,
                "spoofed_frames": self.spoofed_frames,
                "over_budget": self.over_budget(),
            },
        }

    def restore_checkpoint(self, state: Mapping[str, Any]) -> None:
        """Carry on from `checkpoint_state` (raises CheckpointError, changing nothing, for a
        state that does not fit this world)."""
        try:
            counters = state["counters"]
            dropped = {WireDropReason(k): int(v) for k, v in counters["acts_dropped"].items()}
            numbers = [
                int(counters[k])
                for k in ("acts_accepted", "malformed_telemetry", "unknown_senders")
            ] + [int(counters["spoofed_frames"]), int(state["next_sense_ns"])]
            # A checkpoint from before the input budgets: nothing dropped over them.
            over_budget = {
                kind: {name: int(counts.get(name, 0)) for name in self.names}
                for kind, counts in counters.get("over_budget", {}).items()
                if kind in self.budgets
            }
            lockstep = state["lockstep"]
            LockstepBarrier(self.names).resume(lockstep)
            resumes = [
                {"t_s": float(r["t_s"]), "tick": int(r["tick"])} for r in state.get("resumes", [])
            ]
            # A checkpoint from before fault campaigns existed: none injected, no events.
            faults = state.get("faults", {"cursor": 0, "events": 0})
            cursor, event_count = faults["cursor"], int(faults["events"])
            FaultSchedule(self.scenario.faults).restore(cursor)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CheckpointError(f"the world's part does not fit: {exc!r}") from None
        self.engine.restore_checkpoint(state["engine"])
        self.barrier.resume(lockstep)
        self.act_counters.accepted = numbers[0]
        self.act_counters.dropped.update(dropped)
        self.malformed_telemetry, self.unknown_senders, self.spoofed_frames = numbers[1:4]
        for kind, counts in over_budget.items():
            self.budgets[kind].refused.update(counts)
        self.next_sense_ns = numbers[4]
        self.resumes = [*resumes, {"t_s": self.engine.t_s, "tick": self.tick}]
        self.epoch = new_epoch(avoid=state.get("epoch"))
        self._next_checkpoint_ns = self.engine.t_ns + self.checkpoint_period_ns
        self.schedule.restore(cursor)
        self._checkpoint_event_count = event_count

    def _checkpoint_if_due(self) -> None:
        if self._checkpoint_writer is None or self.engine.t_ns < self._next_checkpoint_ns:
            return
        self._next_checkpoint_ns = self.engine.t_ns + self.checkpoint_period_ns
        self._checkpoint_writer.submit(self.tick, self.checkpoint_state())

    @property
    def tick(self) -> int:
        return self.barrier.tick

    @property
    def live(self) -> frozenset[str]:
        return self.barrier.live()

    # -- callbacks -----------------------------------------------------------------------

    def _within_budget(self, kind: str, robot: str) -> bool:
        """Whether `robot`'s message of `kind` is within its budget (world/input_budget.py);
        the first one over it is logged."""
        if self.budgets[kind].take(robot, self.engine.t_ns, time.monotonic_ns()):
            return True
        if (kind, robot) not in self._warned_budget:
            self._warned_budget.add((kind, robot))
            log.warning(
                "%s puts %s faster than %d per control period: the excess is dropped "
                "(summary.json over_budget)",
                robot,
                INPUT_KINDS[kind],
                PER_PERIOD,
            )
        return False

    def _on_act(self, sample: zenoh.Sample) -> None:
        robot = SwarmKeys.chunk(str(sample.key_expr), 3)
        if not self._within_budget("act", robot):
            return
        self._acts.put((robot, sample.payload.to_bytes(), time.monotonic_ns()))
        if self._acts.qsize() >= self._acts_wake_at or self.guard.holding:
            self._wake.set()

    def _on_frame(self, sample: zenoh.Sample) -> None:
        sender = SwarmKeys.last_chunk(str(sample.key_expr))
        if not self._within_budget("frame", sender):
            return
        self._frames.put((sender, sample.payload.to_bytes()))
        if not self.config.lockstep:
            self._frames_queued.set()
        elif self._frames.qsize() >= self._frames_wake_at:
            self._wake.set()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = SwarmKeys.last_chunk(str(sample.key_expr))
        self._liveliness.put((name, sample.kind == zenoh.SampleKind.PUT))
        self._wake.set()

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        # The key names the sender (the router lets robotN put only on its own key); a sample
        # that names another robot is a robot speaking for another, refused like the medium
        # refuses such a radio frame.
        sender = SwarmKeys.last_chunk(str(sample.key_expr))
        if not self._within_budget("telemetry", sender):
            return
        telemetry = parse_message(TelemetryMessage, sample.payload.to_bytes())
        if telemetry is None or telemetry.robot not in self.index or telemetry.robot != sender:
            self.malformed_telemetry += 1
        else:
            self._telemetry.put(telemetry)
            if self._telemetry_wanted:
                self._wake.set()  # a lockstep tick boundary is waiting for it

    def _on_query(self, query: zenoh.Query) -> None:
        """Faults wait for the next tick boundary; every other verb is answered between steps."""
        verb = SwarmKeys.last_chunk(str(query.key_expr))
        (self._fault_admin if verb == "fault" else self._admin).on_query(query)

    # -- queues, drained by the main loop ------------------------------------------------

    def _drain(self) -> None:
        # Token changes queued since the last pass, each robot's last one only (in the order
        # of those): a robot identity that declares and drops its token thousands of times a
        # second made one event, fsynced, and one log line of each, and the world spent
        # minutes on them.  A change undone within one pass (milliseconds) is no restart: a
        # restarted robot boots for a second before its new token comes.
        changes: dict[str, bool] = {}
        while True:
            try:
                name, alive = self._liveliness.get_nowait()
            except queue.Empty:
                break
            changes.pop(name, None)
            changes[name] = alive
        for name, alive in changes.items():
            self._on_liveliness(name, alive)
        if self._token_lost_mono_s:
            self._tokens_lost_for_good()
        # Only the acts queued when this pass began: in real time each act catches the physics
        # up to its arrival, and on a starved machine acts can come faster than that, which
        # would hold the loop here with no sense tick going out.  Later acts wait for the next
        # pass, as acts that come while the loop sleeps do.
        acts: list[tuple[str, bytes, int]] = []
        for _ in range(self._acts.qsize()):
            try:
                acts.append(self._acts.get_nowait())
            except queue.Empty:
                break
        taken: list[tuple[int, ActMessage, int]] = []
        for robot, raw, arrival in acts:
            i = self.index.get(robot)
            act = parse_act(raw) if i is not None else WireDropReason.UNKNOWN_ROBOT
            self.act_counters.count(act)
            if i is not None and not isinstance(act, WireDropReason):
                taken.append((i, act, arrival))
        limit_ns, arrivals_ns = 0, [0] * len(taken)
        if taken and self._catch_up is not None:
            # The clock read at each act's arrival, the act's answer counted from then
            # (`RealTimeGuard.take_answers`), and read again now, after every act of the pass
            # came.  A grid step that does not divide the period must not carry the physics
            # past the next sense tick, nor past the clock.
            names = self.names
            clock_ns, arrivals_ns = self.guard.take_answers(
                time.monotonic_ns(),
                [(names[i], act.tick, arrival) for i, act, arrival in taken],
            )
            limit_ns = min(clock_ns, self.next_sense_ns)
        for (i, act, arrival), arrival_ns in zip(taken, arrivals_ns, strict=True):
            if self._catch_up is not None:
                self._catch_up(arrival_ns, limit_ns)  # the old duty held until this act came
            self._apply_act(i, act, arrival)
        if self.config.lockstep:
            # Deterministic order within one step: by sender index, then arrival.
            self._held_frames.extend(self._queued_frames())
        else:
            self._pass_frames_on()
        self._take_telemetry()
        self._serve_queries()

    def _accept_frame(self, sender: str, payload: bytes) -> int | None:
        """The sender's index if the medium takes the frame from robot `sender`'s transmitter;
        None (counted) for an unknown transmitter or a frame claiming another sender id."""
        j = self.index.get(sender)
        if j is None:
            self.unknown_senders += 1
            return None
        self.barrier.frame(sender)
        if claimed_sender(payload) not in (None, j):
            # The medium knows the antenna: a robot cannot speak for another.
            self.spoofed_frames += 1
            return None
        return j

    def _queued_frames(self) -> list[tuple[int, bytes]]:
        """Every frame queued so far that the medium takes, as (sender index, payload), in
        arrival order."""
        frames: list[tuple[int, bytes]] = []
        while True:
            try:
                sender, payload = self._frames.get_nowait()
            except queue.Empty:
                return frames
            j = self._accept_frame(sender, payload)
            if j is not None:
                frames.append((j, payload))

    def _pass_frames_on(self) -> None:
        """Real time, under the engine's lock: every frame queued so far, in arrival order,
        sent on its links at the world's clock, and every frame due by the clock put on its
        receiver's key."""
        now_ns = self._radio_clock_ns()
        for j, payload in self._queued_frames():
            self.engine.transmit(j, payload, now_ns)
        self._deliver_radio(now_ns)

    def _radio_clock_ns(self) -> int:
        """Real time: the simulation time now (the starvation guard's clock), by which the
        radio medium sends and delivers frames; the engine's time before the clock starts."""
        if not self._time_started:
            return self.engine.t_ns
        return max(self.engine.t_ns, self.guard.sim_time_ns(time.monotonic_ns()))

    def _relay_frames(self) -> None:
        """Real time: the radio medium's own thread.  While the main loop sleeps, frames are
        drawn as soon as they come and, on a link with no delay, put on their receivers' keys
        at once, instead of when the main loop next wakes (docs/scale.md, "The radio hop").
        A frame with a delay waits in the engine's queue and leaves with the first pass of the
        medium at or after its due time, at the latest with the next sense message, as in
        lockstep: a robot takes its frames when it runs its control tick, which the sense
        message starts, so it sees each frame at the same tick as if it had come at its due
        time (unless that tick had begun before).  Nothing wakes for a frame's due time: on a
        link with a delay each frame to each robot has its own, and a pass of the world's loop
        per due time was more than half of the loop's work at 18 robots (docs/scale.md, "The
        world's loop at 18 robots").  Frames are taken from the queue and
        delivered only under the engine's lock, by this thread or by the main loop when it is
        awake (`_drain`), so they leave in arrival order and a busy main loop passes them on
        itself.  The subscriber's callback never waits for the lock.  Ends when `run` sets
        `_relay_stopping`."""
        while True:
            self._frames_queued.wait()
            with self._engine_lock:
                self._frames_queued.clear()
                if self._relay_stopping:
                    return
                try:
                    self._pass_frames_on()
                except Exception:
                    # A world without its radio must not go on as if it had one.
                    log.exception("the radio relay failed: stopping the world")
                    self.stop.set()
                    self._wake.set()
                    return

    def _on_liveliness(self, name: str, alive: bool) -> None:
        if name not in self.index:
            return
        self._note_token(name, alive)
        # A robot that (re)joins starts with a clean slate and is waited for from the next
        # tick on: the sense message of the current tick may have gone out before it was
        # listening.  A token seen again while its seat is live (a router restart) only cleans
        # the slate; an end of a token whose seat is already left (the world dropped it at a
        # fault's tick) changes nothing.
        was_live = name in self.live
        if alive:
            self._token_lost_mono_s.pop(name, None)
            self._join(name, "liveliness", record=not was_live, owes_now=False)
        elif was_live and self.config.lockstep and self._time_started:
            # Held for the grace first: a router restart takes every token and brings it back.
            self._token_lost_mono_s.setdefault(name, time.monotonic())
        elif was_live:
            self.leave_seat(name, "liveliness")

    def _tokens_lost_for_good(self) -> None:
        """Lockstep: robots whose token has been gone for the grace are down at this tick."""
        grace_s = self.config.lockstep_token_grace_s
        now_s = time.monotonic()
        for name, lost_s in list(self._token_lost_mono_s.items()):
            if now_s - lost_s >= grace_s:
                del self._token_lost_mono_s[name]
                if name in self.live:
                    self.leave_seat(name, "liveliness")

    def leave_seat(self, robot: str, cause: str) -> None:
        """The robot is down from this tick on: not waited for, braked; `robot_down`."""
        self._token_lost_mono_s.pop(robot, None)
        self.barrier.leave(robot)
        self.guard.leave(robot)
        self.telemetry_gate.left(robot)
        log.info("robot %s left (%s)", robot, cause)
        if self._time_started:
            self.record("robot_down", robot, {"tick": self.tick, "cause": cause})

    def join_seat(self, robot: str, cause: str) -> None:
        """At a tick boundary, before its sense message: the robot is up and waited for from
        this tick on; `robot_up`."""
        self._join(robot, cause, record=True, owes_now=True)

    def _join(self, robot: str, cause: str, record: bool, owes_now: bool) -> None:
        self._token_lost_mono_s.pop(robot, None)
        self.barrier.join(robot)
        if owes_now:
            # The tick's sense message is still to go out, so the robot hears it; waiting for
            # its answer also keeps the next tick's frames from reaching it before it is done.
            self.barrier.seats[robot].owes_from_tick = self.tick
        self.guard.join(robot)
        self.telemetry_gate.joined(robot, self.engine.t_ns)
        log.info("robot %s joined (%s)", robot, cause)
        if record and self._time_started:
            self.record("robot_up", robot, {"tick": self.tick, "cause": cause})

    def _take_telemetry(self) -> None:
        """Hand what arrived to the gate; in real time it is applied at once."""
        while True:
            try:
                telemetry = self._telemetry.get_nowait()
            except queue.Empty:
                break
            t_ns = round(telemetry.t_s * NS_PER_S)
            if not self.telemetry_gate.arrived(telemetry.robot, t_ns, telemetry, self.engine.t_ns):
                self.telemetry_ahead += 1
                if telemetry.robot not in self._warned_ahead:  # once per robot: not a flood
                    self._warned_ahead.add(telemetry.robot)
                    log.warning(
                        "telemetry of %s stamped t = %.3f s, ahead of the lockstep clock "
                        "(%.3f s): refused and counted in malformed_telemetry",
                        telemetry.robot,
                        telemetry.t_s,
                        self.engine.t_s,
                    )
        if not self.config.lockstep:
            self._apply_telemetry(None)

    def _apply_telemetry(self, t_ns: int | None) -> None:
        """Apply the telemetry the gate releases at `t_ns` (None: all), in its order."""
        for name, telemetry in self.telemetry_gate.release(t_ns):
            self.sense_drops[name] = telemetry.dropped_sense
            leads = telemetry.role == "leader"
            self.reported_roles[name] = (leads, telemetry.term or 0, telemetry.t_s)
            if telemetry.timing is not None:
                self.timing[name] = telemetry.timing
            # A deliberate overload (`tick_slow`) is a fault to watch, not starvation to hide.
            self.guard.exempt_if(name, _overloaded_on_purpose(telemetry))
            self._follow_leader()
        self._follow_leader()

    def _settle_telemetry(self) -> None:
        """Lockstep, at a tick boundary: wait for the telemetry due by now (each robot's own
        period tells when), then apply what is due (module docstring)."""
        deadline = time.monotonic() + TELEMETRY_WAIT_S
        self._telemetry_wanted = True
        try:
            self._await_telemetry(deadline)
        finally:
            self._telemetry_wanted = False
        self._apply_telemetry(self.engine.t_ns)

    def _await_telemetry(self, deadline: float) -> None:
        """Until the telemetry due by now has come, or `deadline` (monotonic s) has passed."""
        while (missing := self.telemetry_gate.waiting_for(self.engine.t_ns)) and not (
            self.stop.is_set()
        ):
            if time.monotonic() > deadline:
                log.warning(
                    "no telemetry from %s for %.1f s: not waited for until it speaks",
                    ", ".join(missing),
                    TELEMETRY_WAIT_S,
                )
                self.telemetry_gate.give_up_on(missing)
                break
            self._wake.wait(0.005)
            self._wake.clear()
            self._drain()

    def _follow_leader(self) -> None:
        """Take the sample's leader from the telemetry (module docstring)."""
        live = self.live
        claims = [
            (term, -self.index[name], name, t_s)
            for name, (leads, term, t_s) in list(self.reported_roles.items())
            if leads and name in live and name in self.index
        ]
        if not claims:
            return
        term, _, name, t_s = max(claims)
        metrics = self.engine.metrics
        if self.index[name] != metrics.leader_index or term != metrics.leader_term:
            previous = metrics.leader_index
            metrics.set_leader(self.index[name], term, t_s)
            log.info("robot %s leads (term %d)", name, term)
            if self.index[name] != previous:
                detail = {"from": self.names[previous], "term": term}
                self.record("leader_change", name, detail, t_s=t_s)

    def _transmit_held(self) -> None:
        for j, payload in sorted(self._held_frames, key=lambda item: item[0]):
            self.engine.transmit(j, payload)
        self._held_frames.clear()

    def _apply_act(self, i: int, act: ActMessage, arrival_mono_ns: int) -> None:
        if self.config.lockstep and act.tick == self.tick:
            self.lockstep_profile.answered(self.names[i], arrival_mono_ns - self._sense_out_mono_ns)
        self.barrier.act(self.names[i], act.tick, act.radio_frames)
        self.guard.answer(self.names[i], act.tick)
        self.duty[i] = np.where(act.enabled, act.duty, 0.0)
        self.act_seen_mono_ns[i] = arrival_mono_ns
        self.act_seen_sim_ns[i] = self.engine.t_ns

    def _publish_sense(self, lockstep: bool, delivered: list[int]) -> None:
        """Every robot's sense message of this tick, encoded at once (wire.py
        `encode_sense_rows`), each on its robot's own key."""
        self._sense_out_mono_ns = time.monotonic_ns()
        pins = self.engine.sense_pins()
        payloads = encode_sense_rows(pins, self.tick, lockstep, delivered, self.epoch)
        for publisher, payload in zip(self._sense_publishers, payloads, strict=True):
            publisher.put(payload)
        self._sense_sent = (pins, self.tick)
        self._sense_sent_mono_ns = time.monotonic_ns()

    def _repeat_sense(self) -> None:
        """Real time, while the guard holds the time: the newest sense messages again (no new
        fix, no frames announced), so the robots know the world is there and wait
        (robot_firmware/tick_scheduler.py)."""
        if self._sense_sent is None:
            return
        pins, tick = self._sense_sent
        again = replace(pins, fix_pose=None)
        no_frames = [0] * len(self.names)
        for publisher, payload in zip(
            self._sense_publishers,
            encode_sense_rows(again, tick, False, no_frames, self.epoch),
            strict=True,
        ):
            publisher.put(payload)
        self._sense_sent_mono_ns = time.monotonic_ns()

    def _deliver_radio(self, until_ns: int | None = None) -> list[int]:
        """Put every frame due by simulation time `until_ns` (default: the engine's time) on
        its receiver's `radio/rx` key, each receiver's in one bundle, in the order they fell
        due (robot_firmware/net/radio_bundle.py); how many frames each robot got."""
        delivered = [0] * len(self.names)
        by_receiver: dict[int, list[bytes]] = {}
        for receiver, _sender, payload in self.engine.due_frames(until_ns):
            by_receiver.setdefault(receiver, []).append(payload)
        for receiver, payloads in by_receiver.items():
            publisher = self._rx_publishers[receiver]
            for bundle in bundle_frames(payloads):
                publisher.put(bundle)
            delivered[receiver] = len(payloads)
        return delivered

    def _dead(self) -> np.ndarray:
        live = self.live
        return np.array([name not in live for name in self.names])

    def _braked_duty(self) -> np.ndarray:
        """Zero for a dead robot, one whose newest act is older than the act time-out in
        simulated time (the world's held time does not age it), and one the starvation guard
        stopped waiting for."""
        stale = self.engine.t_ns - self.act_seen_sim_ns > self.config.act_timeout_ms * 1e6
        braked = self.guard.braked()
        if not braked and not stale.any() and len(self.live) == len(self.names):
            return self.duty.copy()  # every robot drives (the loop's case, event after event)
        lapsed = np.array([name in braked for name in self.names])
        return np.where((stale | self._dead() | lapsed)[:, None], 0.0, self.duty)

    # -- main loop -------------------------------------------------------------------------

    def run(self) -> int:
        cfg = self.config
        # Before the clock starts and before the robots see the world: compiling the kernels
        # on a cold numba cache (the first run after an install or an edit of their sources)
        # held the first physics step for 2.7 s.
        started_s = time.monotonic()
        self.engine.compile_kernels()
        log.debug("world kernels ready in %.1f s", time.monotonic() - started_s)
        session = open_client_until_stopped(
            self.stop, cfg.connect, cfg.zenoh_config, cfg.credentials
        )
        if session is None:
            log.info("stopped before a router let the world in: nothing ran")
            return 0
        with session:
            keys = self.keys
            session.declare_subscriber(keys.act_all, self._on_act)
            frame_subscriber = session.declare_subscriber(keys.radio_tx_all, self._on_frame)
            # Lockstep: frames are part of a tick's answer, taken by the main loop at the
            # barrier.  Real time: a thread of the radio medium relays them as they come.
            relay = (
                None
                if cfg.lockstep
                else threading.Thread(target=self._relay_frames, name="radio-relay", daemon=True)
            )
            session.declare_subscriber(keys.telemetry_all, self._on_telemetry)
            session.liveliness().declare_subscriber(
                keys.alive_all("robot"), self._on_alive, history=True
            )
            session.declare_queryable(keys.admin("world", "*"), self._on_query)
            self._sense_publishers = [session.declare_publisher(keys.sense(n)) for n in self.names]
            self._rx_publishers = [session.declare_publisher(keys.radio_rx(n)) for n in self.names]
            self._session = session
            self._events_pub = session.declare_publisher(keys.events())
            for event in self._unpublished:
                self._events_pub.put(event.model_dump_json().encode())
            self._unpublished.clear()
            clock_pub = session.declare_publisher(keys.clock)
            truth_pub = session.declare_publisher(keys.truth)
            token = session.liveliness().declare_token(keys.alive("world", "world"))
            gc.collect()
            gc.freeze()
            log.info(
                "world up: %d robots, %s, radio %s",
                len(self.names),
                "lockstep" if cfg.lockstep else "real time",
                self.scenario.radio.profile,
            )
            if self.checkpoints is not None:
                self._checkpoint_writer = CheckpointWriter(
                    self.checkpoints, self.checkpoint_failures
                )
            try:
                if relay is None:
                    self._run_lockstep(session, clock_pub, truth_pub)
                else:
                    with self._engine_lock:
                        relay.start()
                        self._run_realtime(session, clock_pub, truth_pub)
            finally:
                if relay is not None:
                    frame_subscriber.undeclare()
                    with self._engine_lock:
                        self._relay_stopping = True
                    self._frames_queued.set()
                    relay.join()
                if self._checkpoint_writer is not None:
                    if self.checkpoints is not None and self.engine.t_ns > 0:
                        self._checkpoint_writer.submit(self.tick, self.checkpoint_state())
                    self._checkpoint_writer.close()
                final_written = self.write_summary(final=True)
                log.info(
                    "world ended at t = %.3f s: %s",
                    self.engine.t_s,
                    "final summary written"
                    if final_written
                    else "final summary could not be written",
                )
                self._session = self._events_pub = None
                token.undeclare()
        return 0 if final_written else EXIT_SUMMARY_NOT_WRITTEN

    @property
    def ran_to_its_end(self) -> bool:
        """Whether the run reached its duration (False for a run without one)."""
        end = self._end_tick()
        return end is not None and self.tick >= end

    def _end_tick(self) -> int | None:
        if self.config.duration_s is None:
            return None
        return round(self.config.duration_s * NS_PER_S / self.period_ns)

    def _run_lockstep(
        self, session: zenoh.Session, clock_pub: zenoh.Publisher, truth_pub: zenoh.Publisher
    ) -> None:
        end = self._end_tick()
        deadline = time.monotonic() + self.config.start_timeout_s
        while not self.stop.is_set() and len(self.live) < len(self.names):
            self._drain()  # wait for the robots to come up before time starts
            if time.monotonic() > deadline:
                log.warning("starting with %d of %d robots", len(self.live), len(self.names))
                break
            self._wake.wait(0.05)
            self._wake.clear()
        self.barrier.start()
        self._time_started = True
        self._clock_started_mono_s = time.monotonic()
        self._clock_started_sim_ns = self.engine.t_ns
        next_summary = time.monotonic() + self.config.summary_every_s
        pacer = LockstepPacer(self.config.max_speed, self._wait_serving_queries)
        clock = time.monotonic_ns
        while not self.stop.is_set() and (end is None or self.tick < end):
            pacer.before_tick(self.engine.t_ns)
            started = clock()
            self._drain()
            self._tick_boundary()
            boundary_done = clock()
            self._publish_sense(lockstep=True, delivered=self._deliver_radio())
            clock_pub.put(
                encode_clock(
                    ClockMessage(self.tick, self.engine.t_ns, self.period_ns, True, self.epoch)
                )
            )
            sense_done = clock()
            # The sample of the bodies as they are now, taken while the robots compute (the
            # acts and frames that come meanwhile change no pose, contact or leader).
            self.engine.record_metrics()
            sampled = clock()
            self._await_answers()
            answered = clock()
            self._drain()
            self._transmit_held()
            gathered = clock()
            self.engine.advance(np.where(self._dead()[:, None], 0.0, self.duty), self.period_ns)
            stepped = clock()
            self.barrier.advance()
            self._publish_truth(truth_pub)
            self._checkpoint_if_due()
            if time.monotonic() >= next_summary:
                next_summary += self.config.summary_every_s
                self.write_summary()
            self.lockstep_profile.tick_done(
                (started, boundary_done, sense_done, sampled, answered, gathered, stepped, clock())
            )

    def _await_answers(self) -> None:
        """Lockstep: until every live robot has answered the tick (its act has come, and the
        frames it announced in it too).  The callbacks wake this loop only once as many acts,
        then frames, are queued as the tick still waits for (a liveliness change wakes it at
        once): one wake-up per tick instead of one per message."""
        unbounded = 1 << 30
        timeout_ns = round(self.config.lockstep_answer_timeout_s * NS_PER_S)
        waited_ns = 0
        looked_ns = self._sense_out_mono_ns
        try:
            while not self.barrier.complete() and not self.stop.is_set():
                acts, frames = self.barrier.owed()
                self._acts_wake_at = max(acts, 1)
                self._frames_wake_at = max(frames, 1) if acts == 0 else unbounded
                # Set, then look: an arrival the callback judged by the old count is seen here.
                if self._acts.qsize() < self._acts_wake_at and (
                    self._frames.qsize() < self._frames_wake_at
                ):
                    self._wake.wait(0.05)
                self._wake.clear()
                self._drain()
                # The time-out counts the time this loop was awake waiting, each pass at most
                # `ANSWER_WAIT_STEP_NS`: a world continued after a freeze of its own first
                # takes the answers that came meanwhile instead of giving up on them.
                now_ns = time.monotonic_ns()
                waited_ns += min(now_ns - looked_ns, ANSWER_WAIT_STEP_NS)
                looked_ns = now_ns
                if waited_ns > timeout_ns and not self.barrier.complete():
                    self._excuse_late_robots()
        finally:
            self._acts_wake_at = self._frames_wake_at = 1

    def _excuse_late_robots(self) -> None:
        """Lockstep: the tick goes on without the answers still owed after the time-out (a
        message to or from those robots was lost; world/lockstep.py "Lost messages")."""
        for name in sorted(self.barrier.waiting()):
            if name in self._token_lost_mono_s:
                continue  # its token went: waited for until the token grace ends
            seat = self.barrier.seats[name]
            log.warning(
                "robot %s has not answered tick %d within %.1f s (last act for tick %d, %d "
                "frames owed): a message was lost; going on, waiting for it from the next tick",
                name,
                self.barrier.tick,
                self.config.lockstep_answer_timeout_s,
                seat.last_act_tick,
                seat.frames_owed,
            )
            self.barrier.excuse(name)

    def _run_realtime(
        self, session: zenoh.Session, clock_pub: zenoh.Publisher, truth_pub: zenoh.Publisher
    ) -> None:
        """Simulation time is wall time since start, held back by the starvation guard
        (world/realtime_guard.py): never more than `starvation_lead_periods` control periods
        beyond the period the slowest live robot has answered.  While it is held, the newest
        sense messages are repeated every period.  The physics is integrated exactly from event
        to event (an act changes a duty, a sense message is due; frames are the radio thread's,
        `_relay_frames`, and never wake this loop):
        `step_bodies` is exact for a held duty, so with the default `act_grid_ms` of 1 this
        equals a 1 kHz loop without its cost: the acts that came within one millisecond change
        their duties together, at its end, in one physics step instead of one each.

        An act does not wake the loop unless the guard holds the time: it carries its arrival
        instant, and the loop, which drains the acts before it moves the physics on, catches
        the physics up to that instant (on the act grid) before it applies the act, so the duty
        changes when the act came all the same.  The guard counts each answer from its
        arrival too (`RealTimeGuard.take_answers`): a robot that answered within its lead of
        two periods holds nothing, however late the loop takes its act.  One wake-up per act
        (N per period) would cost the loop an iteration and a physics step each."""
        end = self._end_tick()
        guard = self.guard
        # A resumed world carries on from the checkpoint's time.
        guard.start(self.tick, self.next_sense_ns, self.engine.t_ns, time.monotonic_ns())
        self._time_started = True
        self._clock_started_mono_s = time.monotonic()
        self._clock_started_sim_ns = self.engine.t_ns
        next_summary = time.monotonic() + self.config.summary_every_s

        self._catch_up = self._catch_up_with_act
        try:
            while not self.stop.is_set() and (end is None or self.tick < end):
                due = self.next_sense_ns
                mono = time.monotonic_ns()
                now_sim = guard.sim_time_ns(mono)
                if now_sim < due and not (guard.holding and not self._acts.empty()):
                    wait_ns = due - now_sim
                    if guard.holding:  # until an act comes, or the sense messages are repeated
                        wait_ns = min(wait_ns, self._sense_sent_mono_ns + self.period_ns - mono)
                    # Asleep, the loop lets the radio relay at the engine (`_relay_frames`).
                    self._engine_lock.release()
                    try:
                        self._wake.wait(max(wait_ns, 0) / NS_PER_S)
                    finally:
                        self._engine_lock.acquire()
                    self._wake.clear()
                # Frames due by the clock leave in the drain, before the physics catches up
                # with the clock: a frame's hop through the world does not wait for a physics
                # step.
                self._drain()
                mono = time.monotonic_ns()
                now_sim = guard.sim_time_ns(mono)
                if now_sim >= self.next_sense_ns:
                    self._advance_physics_to(self.next_sense_ns)
                    self._tick_boundary()
                    self._publish_sense(lockstep=False, delivered=self._deliver_radio())
                    # Late at the check, plus the wall time to the messages' departure.
                    self.sense_lateness.record(
                        now_sim - self.next_sense_ns + self._sense_out_mono_ns - mono
                    )
                    clock_pub.put(
                        encode_clock(
                            ClockMessage(
                                self.tick, self.engine.t_ns, self.period_ns, False, self.epoch
                            )
                        )
                    )
                    guard.published(self.tick)
                    self.barrier.advance()
                    self.next_sense_ns += self.period_ns
                    self._publish_truth(truth_pub)
                    self._checkpoint_if_due()
                else:
                    self._advance_physics_to(now_sim)
                    if guard.holding and mono >= self._sense_sent_mono_ns + self.period_ns:
                        self._repeat_sense()
                while guard.new_lapses:
                    name, answered = guard.new_lapses.pop(0)
                    log.warning(
                        "robot %s held the time for %.1f s (answered tick %s of %d): going on "
                        "without it, its body braked, until it catches up",
                        name,
                        self.config.starvation_hold_limit_s,
                        answered,
                        self.tick - 1,
                    )
                if time.monotonic() >= next_summary:
                    next_summary += self.config.summary_every_s
                    self.write_summary()
        finally:
            self._catch_up = None

    def _advance_physics_to(self, sim_ns: int) -> None:
        """Real time: the physics up to `sim_ns` with the duties held, in exact steps."""
        while self.engine.t_ns < sim_ns:
            step = min(MAX_PHYSICS_STEP_NS, sim_ns - self.engine.t_ns)
            self.engine.advance(self._braked_duty(), step)

    def _catch_up_with_act(self, arrival_ns: int, limit_ns: int) -> None:
        """Real time: the physics up to when an act that came at simulation time `arrival_ns`
        changes its duty (`act_effect_ns` on the `act_grid_ms` grid, not past `limit_ns`),
        before `_drain` applies it."""
        self._advance_physics_to(act_effect_ns(arrival_ns, limit_ns, self._act_grid_ns))

    def _publish_truth(self, truth_pub: zenoh.Publisher) -> None:
        self._record_collisions()
        every = max(1, round(NS_PER_S / (self.config.truth_rate_hz * self.period_ns)))
        if self.tick % every:
            return
        engine = self.engine
        reference, _ = engine.trajectory.evaluate(engine.t_s)
        live = self.live
        truth = TruthMessage(
            t_s=engine.t_s,
            tick=self.tick,
            robots={
                name: RobotTruth(
                    pose=tuple(float(v) for v in engine.bodies.pose[i]), alive=name in live
                )
                for i, name in enumerate(self.names)
            },
            reference=tuple(float(v) for v in reference),
            # Latency percentiles cost a sort: refreshed about once a second.
            radio=self.radio_stats(percentiles=self.tick % (20 * every) == 0),
        )
        truth_pub.put(truth.to_json_bytes())

    def current_position_errors(self) -> dict[str, float]:
        """Each robot's distance from its reference now (trajectory or slot, DESIGN.md §8)."""
        engine = self.engine
        reference, _ = engine.trajectory.evaluate(engine.t_s)
        errors = sample_errors(
            engine.bodies.pose,
            reference_points(
                engine.bodies.pose,
                reference,
                FormationLayout.from_scenario(self.scenario),
                engine.metrics.leader_index,
            ),
        )
        return {
            name: round(float(np.hypot(errors[i, 0], errors[i, 1])), 6)
            for i, name in enumerate(self.names)
        }

    def radio_stats(self, percentiles: bool = True) -> RadioStats:
        radio = self.engine.radio
        p50 = radio.latency_percentile_ms(50) if percentiles else None
        p99 = radio.latency_percentile_ms(99) if percentiles else None
        frames = radio.delivered + radio.dropped
        return RadioStats(
            profile=self.engine.link,
            broadcasts=radio.sent,
            frames=frames,
            delivered=radio.delivered,
            dropped=radio.dropped,
            delivery_ratio=None if frames == 0 else round(radio.delivered / frames, 6),
            latency_p50_ms=None if p50 is None else round(p50, 3),
            latency_p99_ms=None if p99 is None else round(p99, 3),
        )

    def over_budget(self) -> dict[str, dict[str, int]]:
        """Messages dropped over their robot's budget, per kind and robot."""
        return {kind: dict(budget.refused) for kind, budget in self.budgets.items()}

    def refused_input(self) -> RefusedInput:
        """What the world refused from the robots since it started (summary and status)."""
        return RefusedInput(
            malformed_acts=self.act_counters.dropped_total,
            malformed_telemetry=self.malformed_telemetry + self.telemetry_ahead,
            refused_frames={
                "unknown_transmitter": self.unknown_senders,
                "claimed_another_sender": self.spoofed_frames,
            },
            over_budget=self.over_budget(),
        )

    def real_time_factor(self) -> float | None:
        """Simulated seconds per wall second since time started (None before it starts)."""
        if self._clock_started_mono_s is None:
            return None
        wall_s = time.monotonic() - self._clock_started_mono_s
        sim_s = (self.engine.t_ns - self._clock_started_sim_ns) / NS_PER_S
        return round(sim_s / wall_s, 4) if wall_s > 0 else None

    def summary(self) -> dict[str, object]:
        scenario = self.scenario.model_copy(update={"duration_s": max(self.engine.t_s, 1e-9)})
        radio = self.radio_stats()
        summary = build_summary(
            scenario,
            self.engine.summary(),
            scenario.controller_params().fuzzy_enabled,
            self.rule_count_total,
            radio.broadcasts,
            radio.delivered,
        )
        radio_summary = radio.model_dump(mode="json")
        radio_summary["profile"] = radio.profile.model_dump(exclude_none=True)
        summary["radio"] = {"profile_name": str(self.scenario.radio.profile), **radio_summary}
        summary["clock_mode"] = "lockstep" if self.config.lockstep else "real_time"
        if not self.config.lockstep:  # a lockstep summary holds no wall-clock figure
            summary["real_time_factor"] = self.real_time_factor()
            summary["starvation_guard"] = self.guard.stats().as_dict()
            summary["world_loop"] = self.sense_lateness.as_dict()
        else:
            summary["lockstep_excused"] = dict(self.barrier.excused)
        summary["control_timing"] = {
            name: None if (timing := self.timing.get(name)) is None else timing.model_dump()
            for name in self.names
        }
        refused = self.refused_input()
        summary["malformed_acts"] = refused.malformed_acts
        summary["dropped_inputs"] = {
            "act": self.act_counters.dropped_as_dict(),
            "sense": {name: self.sense_drops.get(name) for name in self.names},
        }
        summary["malformed_telemetry"] = refused.malformed_telemetry
        summary["refused_frames"] = refused.refused_frames
        summary["over_budget"] = refused.over_budget
        summary["world_resumes"] = list(self.resumes)
        summary["run_events"] = summarise_events(self.event_log.events)
        return summary

    def write_summary(self, final: bool = False) -> bool:
        """Write summary.json (durably if `final`); False when it could not be written, which
        is counted and logged (`summary_failures`) and leaves the previous file whole."""
        if self.config.out_dir is None:
            return True
        summary = self.summary()
        failures = self.write_failure_counts()
        if failures:
            summary["write_failures"] = failures
        try:
            write_json_atomically(self.config.out_dir / "summary.json", summary, durable=final)
        except OSError as exc:
            self.summary_failures.failed(exc)
            return False
        self.summary_failures.succeeded()
        return True

    def write_failure_counts(self) -> dict[str, int]:
        """The run folder's writes that failed so far, per file; only files with failures."""
        kinds = (self.summary_failures, self.checkpoint_failures, self.event_log.write_failures)
        return {kind.what: kind.failures for kind in kinds if kind.failures}

    def _wait_serving_queries(self, timeout_s: float) -> bool:
        """Sleep up to `timeout_s`, answering admin queries meanwhile; True if stopping."""
        end_s = time.monotonic() + timeout_s
        while (left_s := end_s - time.monotonic()) > 0 and not self.stop.is_set():
            self.stop.wait(min(left_s, 0.05))
            self._serve_queries()
        return self.stop.is_set()

    def admin_handlers(self) -> dict[str, Handler]:
        """The world's admin verbs, served between steps."""
        return {
            "net": self._net_request,
            "status": lambda _body: self._status(),
            "fault": lambda body: self.faults.request(
                body, self._fault_admin.serving_reply_by_unix_ns
            ),
        }

    def _serve_queries(self) -> None:
        if self._admin.pending:
            self._admin.serve(self.admin_handlers())

    # -- faults (world/faults.py): the hub's port --------------------------------------------

    def _tick_boundary(self) -> None:
        """Between two ticks, before the next sense message: telemetry due by now is applied
        (lockstep), then the campaign's faults due now, then the `fault` requests that came,
        then what they hold the tick for (module docstring)."""
        if self.config.lockstep:
            self._settle_telemetry()
        while (entry := self.schedule.next_due(self.engine.t_ns)) is not None:
            log.info("campaign: %s at t = %.3f s", entry.fault.fault, self.engine.t_s)
            self.faults.inject(entry.fault, "schedule")
        self.faults.poll()
        if self._fault_admin.pending:
            self._fault_admin.serve(self.admin_handlers())
        self.faults.settle()

    @property
    def lockstep(self) -> bool:
        return self.config.lockstep

    def apply_network_fault(self, fault: NetworkFault) -> None:
        self.engine.apply_network_fault(fault)
        log.info("network fault: %s", fault.model_dump_json(exclude_none=True))

    def ask(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> bytes | None:
        """One admin request to another process, answered while this world serves its own
        queries; None without an answer."""
        pending = self.ask_later(target, verb, body, timeout_s, reply_by_unix_ns)
        while not self.stop.is_set():
            done, payload = pending.result()
            if done:
                return payload
            self.stop.wait(0.002)
            self._serve_queries()
        return None

    def ask_later(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> PendingAnswer:
        """One admin request to another process, not waited for (world/faults.py `poll`): for
        at most `timeout_s`, and not past `reply_by_unix_ns`, the deadline of the request that
        asked for it (robot_firmware/net/request_deadline.py)."""
        if reply_by_unix_ns is not None:
            timeout_s = min(timeout_s, (reply_by_unix_ns - time.time_ns()) / 1e9)
        pending = PendingAnswer(max(timeout_s, 0.0))
        if self._session is None or timeout_s <= 0:
            pending.on_end()
            return pending
        self._session.get(
            self.keys.admin(target, verb),
            zenoh.handlers.Callback(partial(_take_answer, pending), pending.on_end),
            payload=body,
            attachment=request_attachment(timeout_s),
            timeout=timeout_s,
        )
        return pending

    def send(self, target: str, verb: str, body: bytes) -> None:
        if self._session is not None:
            self._session.get(
                self.keys.admin(target, verb),
                zenoh.handlers.Callback(_ignore_reply),
                payload=body,
                attachment=request_attachment(SEND_TIMEOUT_S),
                timeout=SEND_TIMEOUT_S,
            )

    def await_tokens(self, wanted: dict[str, bool], timeout_s: float) -> set[str]:
        seen: set[str] = set()
        deadline = time.monotonic() + timeout_s
        while len(seen) < len(wanted) and time.monotonic() < deadline and not self.stop.is_set():
            try:
                name, alive = self._liveliness.get(timeout=0.01)
            except queue.Empty:
                self._serve_queries()
                continue
            if name in wanted:
                # The wanted edge, or the other one before it (the old process's end before a
                # restart): the hub takes care of the seat.
                self._note_token(name, alive)
                if alive == wanted[name]:
                    seen.add(name)
            else:
                self._on_liveliness(name, alive)
        if seen:
            self._wait_serving_queries(PEER_TOKEN_GRACE_S)
        return seen

    def _note_token(self, name: str, alive: bool) -> None:
        if alive:
            self._tokens_up.add(name)
        else:
            self._tokens_up.discard(name)

    def token_up(self, robot: str) -> bool:
        return robot in self._tokens_up

    def checkpoint_now(self) -> bool:
        if self.checkpoints is None:
            return False
        if self._checkpoint_writer is not None:
            self._checkpoint_writer.flush()
        try:
            self.checkpoints.save(self.tick, self.checkpoint_state())
        except OSError as exc:
            self.checkpoint_failures.failed(exc)
            return False
        self.checkpoint_failures.succeeded()
        return True

    def hold(self, timeout_s: float) -> None:
        self._wait_serving_queries(timeout_s)

    def record(
        self,
        kind: EventKind,
        subject: str | None,
        detail: dict[str, Any],
        t_s: float | None = None,
    ) -> RunEvent:
        """An event at simulation time `t_s` (default: now): into events.jsonl, durably, and
        onto `swarm/<swarm>/events`."""
        event = RunEvent(
            t_s=self.engine.t_ns / NS_PER_S if t_s is None else t_s,
            kind=kind,
            subject=subject,
            detail=detail,
        )
        self.event_log.append(event)
        if self._events_pub is None:
            self._unpublished.append(event)
        else:
            self._events_pub.put(event.model_dump_json().encode())
        return event

    def _record_collisions(self) -> None:
        """Every contact that began since the last tick, as a `collision` event at its time."""
        for t_s, robot, touched in self.engine.collisions:
            self.record("collision", robot, {"with": touched, "tick": self.tick}, t_s=t_s)
        self.engine.collisions.clear()

    def _status(self) -> WorldStatusReply:
        return WorldStatusReply(
            t_s=self.engine.t_s,
            tick=self.tick,
            clock_mode="lockstep" if self.config.lockstep else "real_time",
            real_time_factor=self.real_time_factor(),
            live=tuple(sorted(self.live)),
            robots=self.names,
            radio=self.radio_stats(),
            network_faults=self.engine.network.report(),
            metrics=RunMetrics.model_validate(self.engine.summary()),
            position_errors_m=self.current_position_errors(),
            lockstep_owed={
                name: LockstepSeat(
                    live=seat.live,
                    last_act_tick=seat.last_act_tick,
                    frames_owed=seat.frames_owed,
                    owes_from_tick=seat.owes_from_tick,
                    excused=self.barrier.excused[name],
                )
                for name, seat in self.barrier.seats.items()
            },
            lockstep_profile=(
                LockstepProfileReport(
                    ticks=self.lockstep_profile.ticks,
                    phase_ms_per_tick=self.lockstep_profile.phase_ms_per_tick(),
                    answer_p50_ms=self.lockstep_profile.answer_p50_ms(),
                )
                if self.config.lockstep
                else None
            ),
            refused_input=self.refused_input(),
            write_failures=self.write_failure_counts(),
        )

    def _net_request(self, payload: bytes) -> NetReply | AdminError:
        """Get the link profile (empty body), switch to a named one ({"profile": NAME}), or
        change some of its fields ({"loss": 0.2, ...}); a bad request changes nothing."""
        if not payload:
            return NetReply(profile=self.engine.link, faults=self.engine.network.report())
        try:
            request = json.loads(payload)
        except (ValueError, RecursionError) as exc:  # ValueError: also not UTF-8
            return AdminError(
                error=f"invalid network profile: not JSON: {exc}", reason=AdminRefusal.NOT_JSON
            )
        if not isinstance(request, dict):
            return AdminError(error="invalid network profile: the request must be a JSON object")
        try:
            if "profile" in request:
                name = NetProfileRequest.model_validate(request).profile
                if name not in PROFILES:
                    known = ", ".join(sorted(PROFILES))
                    return AdminError(
                        error=f"unknown profile {name!r}; known: {known}",
                        reason=AdminRefusal.UNKNOWN_PROFILE,
                    )
                profile = PROFILES[name]
            else:
                merged = {**self.engine.link.model_dump(exclude_none=True), **request}
                profile = LinkProfile.model_validate(merged)
        except ValidationError as exc:
            return AdminError(error=describe_validation_error("invalid network profile", exc))
        self.engine.link = profile
        log.info("radio profile set to %s", profile.model_dump(exclude_none=True))
        return NetReply(profile=profile, faults=self.engine.network.report())

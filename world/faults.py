"""The world as the swarm's fault hub (DESIGN.md §7; the schema is swarm_config/faults.py).

The world owns simulation time, so every fault a user or a campaign injects goes through it and
takes effect at a tick boundary, and every fault and every consequence is recorded with its
simulation time.  This module holds the parts that need no network and no clock, so each is
tested alone (tests/world/test_faults.py); world/runtime.py does the I/O:

* `NetworkFaults`: the radio medium's faults as data: per-link overrides of the scenario's link
  profile (latency, jitter, loss or a burst model) on every link, on the links of one robot or
  on one link (both directions), and the links a partition cuts.  `link_table` turns them into
  the per-link `LinkTable` the radio draw takes (world/radio.py), or None while no network
  fault is active, so a fault-free run draws exactly what it drew before.  Overrides compose:
  a later fault sets the fields it gives on the links it covers and leaves the others as they
  were; setting `loss` replaces a burst model there and `burst` replaces an independent loss;
  partitions add up (each one cuts every link between its robots and the rest); `heal` undoes
  all of it.
* `FaultSchedule`: a scenario's `faults:` campaign and its cursor.  Each entry is due at the
  first tick whose simulation time is at or after its `at_s` (compared in integer
  nanoseconds), entries in time order (the scenario's order among equal times).  The cursor is
  part of the world's checkpoint.
* `EventLog`: `<out>/events.jsonl`, one `RunEvent` per line, each append flushed and fsynced.
  A fresh world empties the file; a world resumed from a checkpoint keeps the lines the
  checkpoint had counted and drops the rest (what happened after it is flown again), so a
  replay writes the same file.
* `TelemetryGate`: when the world takes a robot's telemetry into account (who leads, its loop
  timing).  In real time at once.  In lockstep a telemetry sample stamped t is applied at the
  first tick boundary at or after t + `delay_ns`, and at each boundary the world waits for the
  samples it expects up to then (a robot publishes at a fixed period of its own simulated
  time), so what is applied at which tick does not depend on delivery: a leader change moves
  the metrics at a deterministic tick.  A lockstep robot stamps its telemetry with the time of
  the sense message it answers, so a sample stamped more than `max_ahead_ns` (a control
  period) past the world's clock is one no robot sends: it is refused, since held until its
  stamp it would hold back every later sample of that robot and the world's memory with it.
* `FaultHub`: the world's admin verb `fault` and the campaign's injections.  It validates a
  fault (a malformed body: `invalid_request` / `not_json`; a name outside the swarm:
  `unknown_robot` / `unknown_process`; nothing changes), applies network faults itself,
  forwards register faults to the robot's `fault` verb and process faults to the launcher's
  verbs, and records `fault_injected` or `fault_refused`, with the reason the forwarded-to
  process gave (a robot without the verb answers `unknown_verb`; no answer at all is
  `unreachable`).  In real time a forwarded fault does not hold the world's loop: the request
  goes out, the ticks go on, and at each tick boundary `poll` records and answers the faults
  whose answer came (a frozen or slow robot, or a frozen launcher, used to stop every robot's
  sense messages for as long as the world waited for it).  In lockstep it makes process faults
  deterministic: it waits for the
  launcher's reply while the world holds the tick, drops a killed or stopped robot's seat at
  that tick itself, and after a restart holds the tick until the new process's liveliness token
  is seen, then joins it at that tick (the `settle` step, after the reply went out); a robot
  continued after a freeze longer than its lease, whose token went, is joined the same way once
  its token is back.  A fault on
  the world itself (`kill`, `restart`) is recorded and checkpointed first, then the launcher is
  asked and the world holds until it is killed, so a restarted world resumes exactly there.
  Neither the world's nor the router's `kill`, `restart` or `stop` can be answered (the answer
  would pass through the process cut off): they are recorded as injected when sent.
"""

from __future__ import annotations

import json
import logging
import os
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from robot_firmware.net.answers import DeferredAnswer, PendingAnswer
from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    FaultReply,
    LinkOverride,
    NetworkFaultsReport,
    ProcessRequest,
    refusal_of,
)
from swarm_config.atomic_files import write_file_atomically
from swarm_config.faults import (
    FAULT_ADAPTER,
    PROCESS_ROLES,
    EventKind,
    Fault,
    HealFault,
    NetFault,
    PartitionFault,
    RunEvent,
    ScheduledFault,
    fault_boolean_problems,
    fault_subjects,
    swarm_fault_problem,
)
from swarm_config.radio import BurstLoss, LinkProfile
from swarm_config.settings import describe_problems, describe_validation_error
from world.checkpoint import CheckpointError, decode_array, encode_array
from world.radio import LinkTable
from world.write_failures import WriteFailures

log = logging.getLogger("swarm.world.faults")

NS_PER_S = 1_000_000_000
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
NetworkFault = NetFault | PartitionFault | HealFault
Source = Literal["admin", "schedule"]
"""Where a fault came from: the admin verb, or the scenario's campaign."""

EVENTS_FILE_NAME = "events.jsonl"
FORWARD_TIMEOUT_S = 5.0
"""How long the world waits for a robot's or the launcher's answer to a forwarded fault."""
TOKEN_TIMEOUT_S = 60.0
"""Lockstep: how long the world holds the tick for a restarted robot's liveliness token."""
WORLD_DEATH_TIMEOUT_S = 30.0
"""How long the world holds after asking the launcher to kill or restart it."""

# -- network faults ------------------------------------------------------------------------

_UNSET = -1
_INDEPENDENT = 0
_BURST = 1
_BURST_FIELDS = ("good_to_bad", "bad_to_good", "loss_in_good", "loss_in_bad")


def _number_or_none(value: np.floating[Any]) -> float | None:
    return None if np.isnan(value) else float(value)


class NetworkFaults:
    """The radio medium's network faults: per-link overrides and cut links (module docstring).

    Arrays are sender x receiver (N, N); NaN (or `_UNSET`) where a link keeps the base
    profile's value."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.index = {name: i for i, name in enumerate(self.names)}
        self._clear()

    def _clear(self) -> None:
        n = len(self.names)
        self.latency_ms = np.full((n, n), np.nan)
        self.jitter_ms = np.full((n, n), np.nan)
        self.loss_model = np.full((n, n), _UNSET, dtype=np.int64)
        """Per link: _UNSET (the base profile's model), _INDEPENDENT (`loss`) or _BURST."""
        self.loss = np.full((n, n), np.nan)
        self.burst = np.full((len(_BURST_FIELDS), n, n), np.nan)
        """good_to_bad, bad_to_good, loss_in_good, loss_in_bad per link."""
        self.cut = np.zeros((n, n), dtype=bool)

    @property
    def active(self) -> bool:
        """Whether any link differs from the base profile."""
        return bool(
            np.any(~np.isnan(self.latency_ms))
            or np.any(~np.isnan(self.jitter_ms))
            or np.any(self.loss_model != _UNSET)
            or np.any(self.cut)
        )

    def scope(self, fault: NetFault) -> BoolArray:
        """The links a `net` fault covers: all, every link to or from one robot, or one link
        in both directions.  KeyError for a name outside the swarm."""
        n = len(self.names)
        if fault.link is not None:
            a, b = (self.index[name] for name in fault.link)
            mask = np.zeros((n, n), dtype=bool)
            mask[a, b] = mask[b, a] = True
            return mask
        if fault.robot is not None:
            i = self.index[fault.robot]
            mask = np.zeros((n, n), dtype=bool)
            mask[i, :] = mask[:, i] = True
            return mask
        return np.ones((n, n), dtype=bool)

    def apply(self, fault: NetworkFault) -> None:
        """Take a network fault into account.  KeyError, changing nothing, for a name outside
        the swarm."""
        match fault:
            case NetFault():
                mask = self.scope(fault)
                if fault.latency_ms is not None:
                    self.latency_ms[mask] = fault.latency_ms
                if fault.jitter_ms is not None:
                    self.jitter_ms[mask] = fault.jitter_ms
                if fault.loss is not None:
                    self.loss_model[mask] = _INDEPENDENT
                    self.loss[mask] = fault.loss
                    self.burst[:, mask] = np.nan
                if fault.burst is not None:
                    self.loss_model[mask] = _BURST
                    self.loss[mask] = np.nan
                    for k, name in enumerate(_BURST_FIELDS):
                        self.burst[k][mask] = getattr(fault.burst, name)
            case PartitionFault():
                side = np.zeros(len(self.names), dtype=bool)
                side[[self.index[name] for name in fault.robots]] = True
                self.cut |= side[:, None] != side[None, :]
            case HealFault():
                self._clear()

    def link_table(self, base: LinkProfile) -> LinkTable | None:
        """Every link's profile: `base` where no fault says otherwise; None when no network
        fault is active (the radio then draws from `base` alone, as without faults)."""
        if not self.active:
            return None
        uniform = LinkTable.from_profile(base)
        model = self.loss_model
        burst_here = np.where(model == _UNSET, base.burst is not None, model == _BURST)
        burst_values = {
            name: np.where(model == _BURST, self.burst[k], getattr(uniform, name))
            for k, name in enumerate(_BURST_FIELDS)
        }
        return LinkTable(
            latency_ms=np.where(np.isnan(self.latency_ms), base.latency_ms, self.latency_ms),
            jitter_ms=np.where(np.isnan(self.jitter_ms), base.jitter_ms, self.jitter_ms),
            loss=np.where(model == _INDEPENDENT, self.loss, base.loss),
            burst=burst_here,
            cut=self.cut.copy(),
            range_m=base.range_m,
            **burst_values,
        )

    def report(self) -> NetworkFaultsReport | None:
        """What is in effect, for `swarm net get` and the world's status: the overridden
        links, grouped by what was set on them, and the cut links; None without any."""
        if not self.active:
            return None
        groups: dict[LinkOverride, list[tuple[str, str]]] = {}
        n = len(self.names)
        for i in range(n):
            for j in range(i + 1, n):
                burst = None
                if self.loss_model[i, j] == _BURST:
                    values = (float(v) for v in self.burst[:, i, j])
                    burst = BurstLoss(**dict(zip(_BURST_FIELDS, values, strict=True)))
                override = LinkOverride(
                    links=(),
                    latency_ms=_number_or_none(self.latency_ms[i, j]),
                    jitter_ms=_number_or_none(self.jitter_ms[i, j]),
                    loss=_number_or_none(self.loss[i, j]),
                    burst=burst,
                )
                if override != LinkOverride(links=()):
                    groups.setdefault(override, []).append((self.names[i], self.names[j]))
        return NetworkFaultsReport(
            overrides=tuple(
                override.model_copy(update={"links": tuple(links)})
                for override, links in groups.items()
            ),
            cut_links=tuple(self.cut_links()),
        )

    def cut_links(self) -> list[tuple[str, str]]:
        """The cut links, each pair once (lower index first)."""
        a, b = np.nonzero(np.triu(self.cut, k=1))
        return [(self.names[i], self.names[j]) for i, j in zip(a, b, strict=True)]

    def export_state(self) -> dict[str, object]:
        return {
            "latency_ms": encode_array(self.latency_ms),
            "jitter_ms": encode_array(self.jitter_ms),
            "loss_model": encode_array(self.loss_model),
            "loss": encode_array(self.loss),
            "burst": encode_array(self.burst),
            "cut": encode_array(self.cut),
        }

    def restored(self, state: object) -> NetworkFaults:
        """A copy carrying on from `export_state`; CheckpointError for one that does not fit."""
        if not isinstance(state, dict):
            raise CheckpointError("the network faults are not a mapping")
        fresh = NetworkFaults(self.names)
        for name in ("latency_ms", "jitter_ms", "loss_model", "loss", "burst", "cut"):
            if name not in state:
                raise CheckpointError(f"the network faults lack {name!r}")
            value = decode_array(state[name])
            current = getattr(fresh, name)
            if value.shape != current.shape or value.dtype != current.dtype:
                raise CheckpointError(
                    f"network faults {name}: {value.dtype}{list(value.shape)}, expected "
                    f"{current.dtype}{list(current.shape)}"
                )
            setattr(fresh, name, value)
        return fresh


# -- the campaign's schedule ---------------------------------------------------------------


class FaultSchedule:
    """A scenario's `faults:` in time order, and how many of them were injected (the cursor)."""

    def __init__(self, entries: Sequence[ScheduledFault]) -> None:
        self.entries = tuple(sorted(entries, key=lambda entry: entry.at_s))
        self.cursor = 0

    @staticmethod
    def due_ns(entry: ScheduledFault) -> int:
        return round(entry.at_s * NS_PER_S)

    def next_due(self, t_ns: int) -> ScheduledFault | None:
        """The next entry due at simulation time `t_ns` (the cursor moves past it), or None."""
        if self.cursor < len(self.entries) and t_ns >= self.due_ns(self.entries[self.cursor]):
            self.cursor += 1
            return self.entries[self.cursor - 1]
        return None

    def restore(self, cursor: object) -> None:
        if not isinstance(cursor, int) or not 0 <= cursor <= len(self.entries):
            raise CheckpointError(
                f"schedule cursor {cursor!r} does not fit a schedule of {len(self.entries)}"
            )
        self.cursor = cursor


# -- events.jsonl --------------------------------------------------------------------------


class EventLog:
    """The run's events, in memory and (with a path) in `events.jsonl`, durably appended.

    A write that fails (a full disk) is counted and logged (`write_failures`) and the run goes
    on with the event in memory; the next write that goes through rewrites the whole file from
    memory, so the file holds every event again, none half written."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.events: list[RunEvent] = []
        self.write_failures = WriteFailures("events.jsonl", log)
        self._file_behind = False

    @property
    def count(self) -> int:
        return len(self.events)

    def start(self, keep: int | None) -> None:
        """A fresh run (`keep` None): an empty file.  A resumed one: the first `keep` lines
        stay and are read back, the rest is cut off (a line half written by a killed world
        included)."""
        self.events = []
        if self.path is None:
            return
        offset = 0
        if keep and self.path.exists():
            raw = self.path.read_bytes()
            for line in raw.splitlines(keepends=True)[:keep]:
                if not line.endswith(b"\n"):
                    break
                try:
                    self.events.append(RunEvent.model_validate_json(line))
                except ValidationError:
                    log.error("%s: line %d is not an event", self.path, len(self.events) + 1)
                    break
                offset += len(line)
            if len(self.events) < keep:
                log.warning(
                    "%s holds %d of the %d events the checkpoint counted",
                    self.path,
                    len(self.events),
                    keep,
                )
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("ab") as handle:
                handle.truncate(offset)
                handle.flush()
                os.fsync(handle.fileno())
        except OSError as exc:
            self.write_failures.failed(exc)
            self._file_behind = True

    def append(self, event: RunEvent) -> None:
        self.events.append(event)
        if self.path is None:
            return
        try:
            if self._file_behind:
                lines = b"".join(e.model_dump_json().encode() + b"\n" for e in self.events)
                write_file_atomically(self.path, lines)
            else:
                with self.path.open("ab") as handle:  # events are rare: no file held open
                    handle.write(event.model_dump_json().encode() + b"\n")
                    handle.flush()
                    os.fsync(handle.fileno())
        except OSError as exc:
            self.write_failures.failed(exc)
            self._file_behind = True
            return
        self._file_behind = False
        self.write_failures.succeeded()


# -- telemetry in lockstep -----------------------------------------------------------------

T = TypeVar("T")


@dataclass
class _Reporter(Generic[T]):
    pending: deque[tuple[int, T]] = field(default_factory=deque)
    latest_ns: int | None = None
    """Stamp of the newest sample since the robot joined."""
    interval_ns: int | None = None
    """Between its two newest samples: when the next one is due."""
    expect_from_ns: int | None = None
    """Live: a sample is expected at or after this time (None: not live)."""
    silent: bool = False
    """Timed out once: not waited for again until it speaks."""


class TelemetryGate(Generic[T]):
    """Which telemetry samples the world applies at a tick boundary (module docstring)."""

    def __init__(
        self,
        names: Sequence[str],
        delay_ns: int,
        default_interval_ns: int,
        max_ahead_ns: int | None = None,
    ) -> None:
        """max_ahead_ns: how far past the world's clock a sample may be stamped (None: any)."""
        self.names = tuple(names)
        self.delay_ns = delay_ns
        self.default_interval_ns = default_interval_ns
        self.max_ahead_ns = max_ahead_ns
        self._robots: dict[str, _Reporter[T]] = {name: _Reporter() for name in self.names}

    def arrived(self, name: str, t_ns: int, sample: T, now_ns: int) -> bool:
        """Take a sample stamped `t_ns` that arrived with the world's clock at `now_ns`; False
        (nothing changes) for one stamped more than `max_ahead_ns` past it."""
        if self.max_ahead_ns is not None and t_ns > now_ns + self.max_ahead_ns:
            return False
        robot = self._robots[name]
        if robot.latest_ns is not None and t_ns > robot.latest_ns:
            robot.interval_ns = t_ns - robot.latest_ns
        robot.latest_ns = t_ns if robot.latest_ns is None else max(robot.latest_ns, t_ns)
        robot.silent = False
        robot.pending.append((t_ns, sample))
        return True

    def joined(self, name: str, t_ns: int) -> None:
        robot = self._robots[name]
        robot.latest_ns = None
        robot.interval_ns = None
        robot.expect_from_ns = t_ns
        robot.silent = False

    def left(self, name: str) -> None:
        self._robots[name].expect_from_ns = None

    def give_up_on(self, names: Sequence[str]) -> None:
        for name in names:
            self._robots[name].silent = True

    def waiting_for(self, t_ns: int) -> list[str]:
        """Live robots whose sample stamped at or before `t_ns - delay_ns` is still to come."""
        horizon = t_ns - self.delay_ns
        waiting = []
        for name, robot in self._robots.items():
            if robot.expect_from_ns is None or robot.silent:
                continue
            if robot.latest_ns is None:
                due = robot.expect_from_ns
            else:
                due = robot.latest_ns + (robot.interval_ns or self.default_interval_ns)
            if due <= horizon:
                waiting.append(name)
        return waiting

    def release(self, t_ns: int | None) -> list[tuple[str, T]]:
        """The samples to apply now, stamped at or before `t_ns - delay_ns` (None: all),
        oldest first, ties in robot order."""
        horizon = None if t_ns is None else t_ns - self.delay_ns
        out: list[tuple[int, int, str, T]] = []
        for k, (name, robot) in enumerate(self._robots.items()):
            while robot.pending and (horizon is None or robot.pending[0][0] <= horizon):
                stamp, sample = robot.pending.popleft()
                out.append((stamp, k, name, sample))
        out.sort(key=lambda item: (item[0], item[1]))
        return [(name, sample) for _, _, name, sample in out]


# -- the hub -------------------------------------------------------------------------------


class FaultPort(Protocol):
    """What the hub needs of the world process (world/runtime.py)."""

    @property
    def lockstep(self) -> bool: ...

    @property
    def tick(self) -> int: ...

    @property
    def live(self) -> frozenset[str]: ...

    def apply_network_fault(self, fault: NetworkFault) -> None: ...

    def ask(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> bytes | None:
        """Send an admin request and wait for its answer (serving the world's own queries
        meanwhile), at most `timeout_s` and not past `reply_by_unix_ns` (the deadline of the
        request that asked for it); None when nobody answered."""

    def ask_later(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> PendingAnswer:
        """Send an admin request and return at once; its answer comes into the result."""

    def send(self, target: str, verb: str, body: bytes) -> None:
        """Send an admin request and do not wait for an answer."""

    def leave_seat(self, robot: str, cause: str) -> None:
        """The robot is down from this tick on (records `robot_down`)."""

    def join_seat(self, robot: str, cause: str) -> None:
        """The robot is up from this tick on (records `robot_up`)."""

    def await_tokens(self, wanted: dict[str, bool], timeout_s: float) -> set[str]:
        """Hold the tick until each robot's liveliness token is seen as wanted (True: there);
        those seen.  Other robots' token changes are handled as usual meanwhile."""

    def token_up(self, robot: str) -> bool:
        """Whether the robot's liveliness token is there, as far as the world has heard."""

    def checkpoint_now(self) -> bool:
        """Write a checkpoint of this tick now, durably; False without a checkpoint store."""

    def hold(self, timeout_s: float) -> None:
        """Wait (serving queries) for up to `timeout_s`: the world is about to be killed."""

    def record(self, kind: EventKind, subject: str | None, detail: dict[str, Any]) -> RunEvent:
        """Append an event at the current simulation time."""


@dataclass
class _Settle:
    """What the hub still holds the tick for, after the replies went out."""

    tokens: dict[str, tuple[bool, str, float]] = field(default_factory=dict)
    """robot -> (token wanted, the fault that asks for it, how long to hold for it)."""
    world_death: bool = False


def _reply_json(payload: bytes) -> dict[str, Any] | None:
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def check_fault(fault: Fault, robots: Sequence[str]) -> AdminError | None:
    """A refusal when the fault names anything outside the swarm, else None."""
    if fault.kind == "process":
        process = fault_subjects(fault)[0]
        if process not in robots and process not in PROCESS_ROLES:
            known = ", ".join((*robots, *PROCESS_ROLES))
            return AdminError(
                error=f"no process {process!r}; processes: {known}",
                reason=AdminRefusal.UNKNOWN_PROCESS,
            )
        return None
    unknown = [name for name in fault_subjects(fault) if name not in robots]
    if unknown:
        return AdminError(
            error=f"no robot {unknown[0]!r} in this swarm; robots: {', '.join(robots)}",
            reason=AdminRefusal.UNKNOWN_ROBOT,
        )
    problem = swarm_fault_problem(fault, robots)
    if problem is not None:
        return AdminError(error=problem, reason=AdminRefusal.INVALID_REQUEST)
    return None


@dataclass
class _Forward:
    """A fault forwarded in real time whose answer the hub has not had yet."""

    fault: Fault
    source: Source
    target: str
    answer: PendingAnswer
    deferred: DeferredAnswer


class FaultHub:
    """Injects faults at a tick boundary and records them (module docstring)."""

    def __init__(self, robots: Sequence[str], port: FaultPort) -> None:
        self.robots = tuple(robots)
        self.port = port
        self._settle = _Settle()
        self._forwards: list[_Forward] = []

    @property
    def forwards_waiting(self) -> int:
        """Faults forwarded in real time whose answer has not come yet."""
        return len(self._forwards)

    # -- entry points ----------------------------------------------------------------------

    def request(
        self, body: bytes, reply_by_unix_ns: int | None = None
    ) -> FaultReply | AdminError | DeferredAnswer:
        """The world's admin verb `fault`: one fault as JSON; a fault forwarded in real time
        is answered once the robot or the launcher has (`poll`).  A forward goes with the
        request's own deadline, when it has one: its sender stops waiting then, and the robot
        or the launcher must not carry out what the sender was told had no answer."""
        try:
            booleans = fault_boolean_problems(json.loads(body))
        except (ValueError, RecursionError):  # not JSON: the adapter below says so
            booleans = []
        if booleans:  # pydantic would take true for 1: `"extra_ms": true` was 1 ms
            refusal = AdminError(
                error=describe_problems("invalid fault", booleans),
                reason=AdminRefusal.INVALID_REQUEST,
            )
            self._record_refusal(None, "admin", refusal)
            return refusal
        try:
            fault: Fault = FAULT_ADAPTER.validate_json(body)
        except ValidationError as exc:
            refusal = AdminError(
                error=describe_validation_error("invalid fault", exc), reason=refusal_of(exc)
            )
            self._record_refusal(None, "admin", refusal)
            return refusal
        return self.inject(fault, "admin", reply_by_unix_ns)

    def inject(
        self, fault: Fault, source: Source, reply_by_unix_ns: int | None = None
    ) -> FaultReply | AdminError | DeferredAnswer:
        """Apply or forward one fault now, and record what became of it (in real time, for a
        forwarded fault, when `poll` finds its answer)."""
        refusal = check_fault(fault, self.robots)
        if refusal is not None:
            self._record_refusal(fault, source, refusal)
            return refusal
        if isinstance(fault, NetFault | PartitionFault | HealFault):
            self.port.apply_network_fault(fault)
            return FaultReply(event=self._record_injected(fault, source))
        if fault.kind == "register":
            return self._forward_register(fault, source, reply_by_unix_ns)
        return self._process(fault, source, reply_by_unix_ns)

    def settle(self) -> None:
        """Hold the tick for what the faults injected at it wait for (lockstep restarts: the
        new token; a kill: the token's end, so that every robot heard of it before the next
        tick; the world's own death)."""
        settle, self._settle = self._settle, _Settle()
        for robot, (alive, cause, timeout_s) in settle.tokens.items():
            if robot not in self.port.await_tokens({robot: alive}, timeout_s):
                log.warning(
                    "%s: the token of %s was not %s within %.0f s",
                    cause,
                    robot,
                    "seen" if alive else "gone",
                    timeout_s,
                )
            elif alive and robot not in self.port.live:
                self.port.join_seat(robot, cause)
        if settle.world_death:
            self.port.hold(WORLD_DEATH_TIMEOUT_S)
            refusal = AdminError(
                error=f"the launcher did not end this world within {WORLD_DEATH_TIMEOUT_S:.0f} s",
                reason=AdminRefusal.UNREACHABLE,
            )
            self.port.record(
                "fault_refused", "world", {"reason": refusal.reason, "error": refusal.error}
            )

    def poll(self) -> None:
        """Real time: record and answer each forwarded fault whose answer came, or never will.
        The world's loop calls it at every tick boundary, so a robot or a launcher that does
        not answer holds nobody's sense messages back."""
        waiting: list[_Forward] = []
        for forward in self._forwards:
            done, payload = forward.answer.result()
            if not done:
                waiting.append(forward)
                continue
            outcome = self._forwarded(
                forward.fault, forward.source, forward.target, payload, forward.answer.waited_s()
            )
            forward.deferred.complete(outcome)
        self._forwards = waiting

    # -- kinds -----------------------------------------------------------------------------

    def _forward(
        self,
        fault: Fault,
        source: Source,
        target: str,
        verb: str,
        body: bytes,
        reply_by_unix_ns: int | None,
    ) -> FaultReply | AdminError | DeferredAnswer:
        """Ask `target` to carry the fault out: in lockstep while the world holds the tick, in
        real time without holding it (`poll`)."""
        if self.port.lockstep:
            answer = self.port.ask(target, verb, body, FORWARD_TIMEOUT_S, reply_by_unix_ns)
            return self._forwarded(fault, source, target, answer)
        pending = self.port.ask_later(target, verb, body, FORWARD_TIMEOUT_S, reply_by_unix_ns)
        forward = _Forward(fault, source, target, pending, DeferredAnswer())
        self._forwards.append(forward)
        return forward.deferred

    def _forward_register(
        self, fault: Fault, source: Source, reply_by_unix_ns: int | None
    ) -> FaultReply | AdminError | DeferredAnswer:
        robot = fault_subjects(fault)[0]
        if robot not in self.port.live:
            refusal = AdminError(
                error=f"{robot} is not up: a register fault needs its process",
                reason=AdminRefusal.UNREACHABLE,
            )
            self._record_refusal(fault, source, refusal)
            return refusal
        body = FAULT_ADAPTER.dump_json(fault)
        return self._forward(fault, source, robot, "fault", body, reply_by_unix_ns)

    def _process(
        self, fault: Fault, source: Source, reply_by_unix_ns: int | None
    ) -> FaultReply | AdminError | DeferredAnswer:
        process = fault_subjects(fault)[0]
        verb = fault.fault
        body = ProcessRequest(process=process).to_json_bytes()
        if process in ("world", "router") and verb in ("kill", "restart", "stop"):
            # No answer can come back (it would pass through the process being cut off): the
            # fault is recorded first, and the world checkpoints before its own end.
            self.settle()
            event = self._record_injected(fault, source)
            if process == "world" and verb != "stop":
                self.port.checkpoint_now()
                self._settle.world_death = True
            self.port.send("launcher", verb, body)
            return FaultReply(event=event)
        outcome = self._forward(fault, source, "launcher", verb, body, reply_by_unix_ns)
        if isinstance(outcome, FaultReply) and self.port.lockstep and process in self.robots:
            self._seat_after(process, verb)
        return outcome

    def _seat_after(self, robot: str, verb: str) -> None:
        """Lockstep: the seat of a robot whose process the launcher just changed."""
        live = robot in self.port.live
        if verb in ("kill", "stop", "restart") and live:
            self.port.leave_seat(robot, verb)
        if verb == "kill" and live:
            # Every robot hears of the death before the next tick: peers act on tokens.
            self._settle.tokens[robot] = (False, verb, FORWARD_TIMEOUT_S)
        elif verb == "restart":
            self._settle.tokens[robot] = (True, verb, TOKEN_TIMEOUT_S)
        elif verb == "cont" and not live:
            if self.port.token_up(robot):
                self.port.join_seat(robot, verb)
            else:
                # Frozen past its liveliness lease: the router dropped its session, and it
                # reconnects now.  Joined once its token is back (and its subscriptions with
                # it), so the tick's sense message and frames cannot go out before it listens.
                self._settle.tokens[robot] = (True, verb, TOKEN_TIMEOUT_S)

    def _forwarded(
        self,
        fault: Fault,
        source: Source,
        target: str,
        payload: bytes | None,
        waited_s: float | None = None,
    ) -> FaultReply | AdminError:
        if payload is None:
            waited = "" if waited_s is None else f" (gave up after {waited_s:.1f} s)"
            refusal = AdminError(
                error=f"{target} did not answer{waited}", reason=AdminRefusal.UNREACHABLE
            )
            self._record_refusal(fault, source, refusal)
            return refusal
        reply = _reply_json(payload)
        if reply is None or reply.get("ok") is not True:
            refusal = AdminError(
                error=f"{target} refused: {(reply or {}).get('error', 'an unreadable answer')}",
                reason=str((reply or {}).get("reason", AdminRefusal.INVALID_REQUEST.value)),
            )
            self._record_refusal(fault, source, refusal)
            return refusal
        event = self._record_injected(fault, source)
        return FaultReply(event=event, reply=reply)

    # -- records ---------------------------------------------------------------------------

    def _detail(self, fault: Fault | None, source: str) -> dict[str, Any]:
        detail: dict[str, Any] = {}
        if fault is not None:
            detail["fault"] = FAULT_ADAPTER.dump_python(fault, mode="json", exclude_none=True)
        detail["source"] = source
        detail["tick"] = self.port.tick
        return detail

    @staticmethod
    def _subject(fault: Fault | None) -> str | None:
        if fault is None:
            return None
        return ",".join(fault_subjects(fault)) or None

    def _record_injected(self, fault: Fault, source: str) -> RunEvent:
        return self.port.record("fault_injected", self._subject(fault), self._detail(fault, source))

    def _record_refusal(self, fault: Fault | None, source: str, refusal: AdminError) -> None:
        detail = self._detail(fault, source)
        detail["reason"] = refusal.reason
        detail["error"] = refusal.error
        self.port.record("fault_refused", self._subject(fault), detail)

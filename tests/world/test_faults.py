"""The world as fault hub (world/faults.py): network faults of the radio medium, the campaign's
cursor, events.jsonl, the lockstep telemetry gate, and the `fault` verb's decisions, all without
a network."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel

from robot_firmware.net.answers import DeferredAnswer, PendingAnswer
from robot_firmware.net.messages import AdminError, AdminRefusal, FaultReply
from swarm_config.faults import (
    FAULT_ADAPTER,
    EventKind,
    HealFault,
    NetFault,
    PartitionFault,
    RunEvent,
    ScheduledFault,
)
from swarm_config.radio import PROFILES, BurstLoss, LinkProfile
from swarm_config.scenario import load_scenario
from world.checkpoint import CheckpointError
from world.engine import WorldEngine
from world.faults import (
    FORWARD_TIMEOUT_S,
    EventLog,
    FaultHub,
    FaultSchedule,
    NetworkFault,
    NetworkFaults,
    TelemetryGate,
)
from world.radio import LinkTable, draw_links
from world.runtime import WorldConfig, WorldProcess
from world.summary import summarise_events

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
CAMPAIGNS = ROOT / "configs" / "campaigns"
NAMES = ("robot1", "robot2", "robot3")
LAB = PROFILES["lab"]
MS = 1_000_000


def _net(**fields: Any) -> NetFault:
    return NetFault(fault="net", **fields)


# -- network faults ------------------------------------------------------------------------


def test_no_network_fault_means_no_link_table() -> None:
    faults = NetworkFaults(NAMES)
    assert not faults.active and faults.link_table(LAB) is None
    faults.apply(_net(loss=0.5))
    faults.apply(HealFault(fault="heal"))
    assert not faults.active and faults.link_table(LAB) is None


def test_a_robots_fault_covers_every_link_to_or_from_it_and_no_other() -> None:
    faults = NetworkFaults(NAMES)
    faults.apply(_net(robot="robot2", loss=0.4, latency_ms=80.0))
    table = faults.link_table(LAB)
    assert table is not None
    loss = np.asarray(table.loss)
    latency = np.asarray(table.latency_ms)
    for i in range(3):
        for j in range(3):
            touches = 1 in (i, j)
            assert loss[i, j] == (0.4 if touches else LAB.loss), (i, j)
            assert latency[i, j] == (80.0 if touches else LAB.latency_ms), (i, j)
            assert table.jitter_ms[i, j] == LAB.jitter_ms


def test_a_links_fault_covers_both_directions_of_that_link_only() -> None:
    faults = NetworkFaults(NAMES)
    faults.apply(_net(link=("robot3", "robot1"), jitter_ms=9.0))
    table = faults.link_table(LAB)
    assert table is not None
    jitter = np.asarray(table.jitter_ms)
    expected = np.full((3, 3), LAB.jitter_ms)
    expected[0, 2] = expected[2, 0] = 9.0
    np.testing.assert_array_equal(jitter, expected)


def test_later_faults_change_only_the_fields_they_give_and_a_loss_model_replaces_the_other() -> (
    None
):
    faults = NetworkFaults(NAMES)
    burst = BurstLoss(good_to_bad=0.1, bad_to_good=0.5, loss_in_bad=0.8)
    faults.apply(_net(loss=0.3))
    faults.apply(_net(robot="robot1", latency_ms=40.0))
    faults.apply(_net(link=("robot1", "robot2"), burst=burst))
    table = faults.link_table(LAB)
    assert table is not None
    burst_links = np.asarray(table.burst)
    assert burst_links[0, 1] and burst_links[1, 0] and burst_links.sum() == 2
    assert table.loss[1, 2] == 0.3 and table.latency_ms[1, 2] == LAB.latency_ms
    assert table.loss[0, 2] == 0.3 and table.latency_ms[0, 2] == 40.0
    assert table.loss_in_bad[0, 1] == 0.8 and table.latency_ms[0, 1] == 40.0
    faults.apply(_net(link=("robot2", "robot1"), loss=0.0))
    table = faults.link_table(LAB)
    assert table is not None and not np.any(table.burst)
    assert table.loss[0, 1] == 0.0


def test_partitions_cut_every_link_across_and_add_up() -> None:
    faults = NetworkFaults(("a", "b", "c", "d"))
    faults.apply(PartitionFault(fault="partition", robots=("b",)))
    assert faults.cut_links() == [("a", "b"), ("b", "c"), ("b", "d")]
    faults.apply(PartitionFault(fault="partition", robots=("c", "d")))
    assert faults.cut_links() == [("a", "b"), ("a", "c"), ("a", "d"), ("b", "c"), ("b", "d")]
    table = faults.link_table(LinkProfile())
    assert table is not None and np.array_equal(table.cut, faults.cut)
    assert not np.any(np.diag(faults.cut))
    faults.apply(HealFault(fault="heal"))
    assert faults.cut_links() == [] and not faults.active


def test_a_fault_naming_a_robot_outside_the_swarm_changes_nothing() -> None:
    faults = NetworkFaults(NAMES)
    before = faults.export_state()
    with pytest.raises(KeyError):
        faults.apply(_net(link=("robot1", "robot9"), loss=1.0))
    with pytest.raises(KeyError):
        faults.apply(PartitionFault(fault="partition", robots=("robot2", "ghost")))
    assert faults.export_state() == before


def test_network_faults_survive_a_checkpoint_and_a_bad_one_is_refused() -> None:
    faults = NetworkFaults(NAMES)
    faults.apply(_net(robot="robot3", burst=BurstLoss(good_to_bad=0.2, bad_to_good=0.2)))
    faults.apply(PartitionFault(fault="partition", robots=("robot1",)))
    state = json.loads(json.dumps(faults.export_state()))
    restored = NetworkFaults(NAMES).restored(state)
    assert restored.export_state() == faults.export_state()
    assert restored.link_table(LAB) is not None
    with pytest.raises(CheckpointError, match="expected float64"):
        NetworkFaults(("x", "y")).restored(state)
    with pytest.raises(CheckpointError, match="lack"):
        NetworkFaults(NAMES).restored({k: v for k, v in state.items() if k != "loss"})


def test_a_partition_alone_draws_what_the_profile_draws_but_on_the_cut_links() -> None:
    """Only the cut decides more: the same uniform numbers, the same delays."""
    faults = NetworkFaults(NAMES)
    faults.apply(PartitionFault(fault="partition", robots=("robot2",)))
    table = faults.link_table(PROFILES["bursty"])
    assert table is not None
    senders = np.array([0, 1, 2])
    state = np.zeros((3, 3), dtype=bool)
    plain = draw_links(PROFILES["bursty"], state, None, np.random.default_rng(5))
    cut = draw_links(table.rows(senders), state, None, np.random.default_rng(5))
    np.testing.assert_array_equal(cut.delay_s, plain.delay_s)
    np.testing.assert_array_equal(cut.in_bad_state, plain.in_bad_state)
    np.testing.assert_array_equal(cut.delivered, plain.delivered & ~faults.cut)


def test_a_uniform_table_draws_exactly_what_its_profile_draws() -> None:
    """A profile, the table of it (both drawn on the path for one profile) and a table with the
    profile's values in every link's own entry (the general path) draw the same fates."""
    for profile in (*PROFILES.values(), LinkProfile(latency_ms=5.0, range_m=2.0)):
        state = np.random.default_rng(1).random((4, 3)) < 0.3
        length = np.random.default_rng(2).random((4, 3)) * 4.0
        table = LinkTable.from_profile(profile)
        per_link = dataclasses.replace(
            table,
            latency_ms=np.full((4, 3), table.latency_ms),
            loss=np.full((4, 3), table.loss),
            burst=np.full((4, 3), table.burst),
            cut=np.zeros((4, 3), dtype=bool),
        )
        assert table.uniform and not per_link.uniform
        a = draw_links(profile, state, length, np.random.default_rng(9))
        for other in (table, per_link):
            b = draw_links(other, state, length, np.random.default_rng(9))
            for x, y in ((a.delivered, b.delivered), (a.delay_s, b.delay_s)):
                np.testing.assert_array_equal(x, y)
            np.testing.assert_array_equal(a.in_bad_state, b.in_bad_state)


def _engine() -> WorldEngine:
    return WorldEngine(load_scenario(PAPER))


def _broadcast_rounds(engine: WorldEngine, rounds: int) -> list[tuple[int, int, int]]:
    for k in range(rounds):
        for sender in range(engine.robot_count):
            engine.transmit(sender, bytes([sender, k % 256]))
        engine.advance(np.zeros((engine.robot_count, 4)), 10 * MS)
    engine.advance(np.zeros((engine.robot_count, 4)), 1000 * MS)
    return [(r, s, p[1]) for r, s, p in engine.due_frames()]


def test_a_healed_fault_leaves_the_radio_drawing_as_if_there_had_been_none() -> None:
    plain, healed = _engine(), _engine()
    healed.apply_network_fault(_net(loss=1.0, latency_ms=500.0))
    healed.apply_network_fault(HealFault(fault="heal"))
    assert healed.params.link_table is None
    assert _broadcast_rounds(plain, 200) == _broadcast_rounds(healed, 200)


def test_the_engine_drops_every_frame_on_a_faulted_robots_links_and_keeps_the_others() -> None:
    engine = _engine()
    engine.link = PROFILES["ideal"]
    engine.apply_network_fault(_net(robot="robot2", loss=1.0))
    delivered = _broadcast_rounds(engine, 50)
    assert delivered and all(1 not in (r, s) for r, s, _ in delivered)
    assert len(delivered) == 50 * 2  # robot1 <-> robot3, both ways
    assert engine.radio.dropped == 50 * 4
    # A new base profile keeps the fault's links as they are.
    engine.link = PROFILES["lab"]
    table = engine.params.link_table
    assert table is not None and table.loss[0, 1] == 1.0 and table.loss[0, 2] == LAB.loss


def test_the_engines_checkpoint_carries_its_network_faults() -> None:
    engine = _engine()
    engine.apply_network_fault(PartitionFault(fault="partition", robots=("robot3",)))
    engine.apply_network_fault(_net(link=("robot1", "robot2"), latency_ms=30.0))
    state = json.loads(json.dumps(engine.checkpoint_state()))
    fresh = _engine()
    fresh.restore_checkpoint(state)
    assert fresh.network.cut_links() == engine.network.cut_links()
    assert fresh.params.link_table is not None
    assert _broadcast_rounds(fresh, 30) == _broadcast_rounds(engine, 30)
    old = dict(state)
    del old["network"]  # a checkpoint from before network faults
    older = _engine()
    older.restore_checkpoint(old)
    assert older.params.link_table is None


# -- the schedule ---------------------------------------------------------------------------


def _entry(at_s: float, fault: dict[str, Any]) -> ScheduledFault:
    return ScheduledFault.model_validate({"at_s": at_s, "fault": fault})


def test_schedule_entries_fall_due_at_the_first_tick_at_or_after_their_time_in_order() -> None:
    heal = _entry(2.0, {"fault": "heal"})
    kill = _entry(0.015, {"fault": "kill", "process": "robot2"})
    cut = _entry(2.0, {"fault": "partition", "robots": ["robot3"]})
    schedule = FaultSchedule([heal, kill, cut])
    due = []
    for tick in range(300):
        while (entry := schedule.next_due(tick * 10 * MS)) is not None:
            due.append((tick, entry))
    assert due == [(2, kill), (200, heal), (200, cut)]
    assert schedule.cursor == 3 and schedule.next_due(10**12) is None


def test_a_schedule_cursor_is_restored_and_a_bad_one_refused() -> None:
    entries = [_entry(1.0, {"fault": "heal"}), _entry(3.0, {"fault": "heal"})]
    schedule = FaultSchedule(entries)
    schedule.restore(1)
    assert schedule.next_due(2 * NS) is None and schedule.next_due(3 * NS) == entries[1]
    for bad in (-1, 3, "1", 1.0, None):
        with pytest.raises(CheckpointError):
            FaultSchedule(entries).restore(bad)


NS = 1_000_000_000


def test_the_shipped_campaigns_are_valid_scenarios() -> None:
    kinds = {}
    for path in sorted(CAMPAIGNS.glob("*.yaml")):
        scenario = load_scenario(path)
        assert scenario.faults, path
        kinds[path.stem] = [(e.at_s, e.fault.fault) for e in scenario.faults]
    assert kinds["leader-failover"] == [(25.0, "kill"), (40.0, "restart")]
    assert load_scenario(CAMPAIGNS / "leader-failover.yaml").duration_s == 60.0
    assert [k for _, k in kinds["world-restart"]] == ["restart", "partition", "heal"]


# -- events.jsonl ---------------------------------------------------------------------------


def _event(t_s: float, kind: EventKind = "fault_injected", subject: str | None = None) -> RunEvent:
    return RunEvent(t_s=t_s, kind=kind, subject=subject)


def test_events_are_appended_one_line_each_and_a_resumed_log_keeps_what_was_counted(
    tmp_path: Path,
) -> None:
    path = tmp_path / "events.jsonl"
    log = EventLog(path)
    log.start(None)
    for k in range(4):
        log.append(_event(float(k)))
    lines = path.read_bytes().splitlines()
    assert [RunEvent.model_validate_json(line).t_s for line in lines] == [0.0, 1.0, 2.0, 3.0]
    with path.open("ab") as handle:
        handle.write(b'{"t_s": 4.0, "ki')  # a world killed mid-line
    resumed = EventLog(path)
    resumed.start(2)
    assert [e.t_s for e in resumed.events] == [0.0, 1.0]
    resumed.append(_event(9.0))
    assert [RunEvent.model_validate_json(x).t_s for x in path.read_bytes().splitlines()] == [
        0.0,
        1.0,
        9.0,
    ]
    fresh = EventLog(path)
    fresh.start(None)
    assert path.read_bytes() == b"" and fresh.count == 0


def test_a_log_shorter_than_the_checkpoint_counted_keeps_what_it_has(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    path.write_bytes(_event(1.0).model_dump_json().encode() + b"\nnot an event\n")
    log = EventLog(path)
    log.start(5)
    assert log.count == 1 and path.read_bytes().count(b"\n") == 1


# -- the telemetry gate ---------------------------------------------------------------------


def test_lockstep_telemetry_is_applied_a_fixed_delay_after_its_stamp() -> None:
    gate: TelemetryGate[str] = TelemetryGate(
        ("a", "b"), delay_ns=20 * MS, default_interval_ns=50 * MS
    )
    gate.arrived("b", 0, "b0", now_ns=0)
    gate.arrived("a", 0, "a0", now_ns=0)
    gate.arrived("a", 50 * MS, "a50", now_ns=0)
    assert gate.release(10 * MS) == []
    assert gate.release(20 * MS) == [("a", "a0"), ("b", "b0")]
    assert gate.release(69 * MS) == []
    assert gate.release(70 * MS) == [("a", "a50")]
    gate.arrived("b", 60 * MS, "b60", now_ns=0)
    assert gate.release(None) == [("b", "b60")]


def test_a_boundary_waits_for_the_telemetry_each_live_robot_owes_by_its_own_period() -> None:
    gate: TelemetryGate[str] = TelemetryGate(
        ("a", "b"), delay_ns=20 * MS, default_interval_ns=50 * MS
    )
    gate.joined("a", 0)
    assert gate.waiting_for(10 * MS) == []
    assert gate.waiting_for(20 * MS) == ["a"]  # its first sample, at or after the join
    gate.arrived("a", 10 * MS, "x", now_ns=0)
    assert gate.waiting_for(79 * MS) == []  # next due at 60 ms (default period)
    assert gate.waiting_for(80 * MS) == ["a"]
    gate.arrived("a", 40 * MS, "y", now_ns=0)  # its own period: 30 ms
    assert gate.waiting_for(89 * MS) == []
    assert gate.waiting_for(90 * MS) == ["a"]
    gate.give_up_on(["a"])
    assert gate.waiting_for(10**12) == []
    gate.arrived("a", 70 * MS, "z", now_ns=0)  # it speaks again: waited for again
    assert gate.waiting_for(120 * MS) == ["a"]
    gate.left("a")
    assert gate.waiting_for(10**12) == []


def test_a_sample_stamped_ahead_of_the_clock_is_refused_and_holds_nothing_back() -> None:
    """With `max_ahead_ns`, a sample stamped past the world's clock by more than that is
    refused (False, nothing changes); had it been taken, it would sit first in the robot's
    queue until its stamp and hold back every later sample of the robot."""
    gate: TelemetryGate[str] = TelemetryGate(
        ("a", "b"), delay_ns=20 * MS, default_interval_ns=50 * MS, max_ahead_ns=10 * MS
    )
    gate.joined("a", 0)
    assert gate.arrived("a", 0, "a0", now_ns=0)
    assert gate.arrived("a", 10 * MS, "a10", now_ns=0)  # one period ahead: still taken
    assert not gate.arrived("a", 10 * MS + 1, "lie", now_ns=0)
    assert not gate.arrived("a", 10**18, "lie", now_ns=40 * MS)
    assert gate.waiting_for(80 * MS) == ["a"]  # its next sample (due at 20 ms) still owed
    assert gate.arrived("a", 40 * MS, "a40", now_ns=40 * MS)
    assert gate.release(60 * MS) == [("a", "a0"), ("a", "a10"), ("a", "a40")]
    unbounded: TelemetryGate[str] = TelemetryGate(("a",), delay_ns=0, default_interval_ns=MS)
    assert unbounded.arrived("a", 10**18, "far", now_ns=0)  # real time: no bound


# -- the hub ----------------------------------------------------------------------------------


@dataclass
class FakePort:
    """The world as the hub sees it, recording what was asked of it."""

    lockstep: bool = True
    tick: int = 1500
    live: frozenset[str] = frozenset(NAMES)
    answers: dict[tuple[str, str], bytes | None] = field(default_factory=dict)
    tokens_seen: bool = True
    tokens_up: frozenset[str] = frozenset(NAMES)
    calls: list[tuple[Any, ...]] = field(default_factory=list)
    events: list[RunEvent] = field(default_factory=list)
    pending: list[PendingAnswer] = field(default_factory=list)
    clock_s: float = 0.0
    reply_by: list[int | None] = field(default_factory=list)

    def apply_network_fault(self, fault: NetworkFault) -> None:
        self.calls.append(("network", fault.fault))

    def ask(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> bytes | None:
        self.calls.append(("ask", target, verb, json.loads(body)))
        self.reply_by.append(reply_by_unix_ns)
        return self.answers.get((target, verb))

    def ask_later(
        self,
        target: str,
        verb: str,
        body: bytes,
        timeout_s: float,
        reply_by_unix_ns: int | None = None,
    ) -> PendingAnswer:
        self.calls.append(("ask_later", target, verb, json.loads(body)))
        self.reply_by.append(reply_by_unix_ns)
        pending = PendingAnswer(timeout_s, clock=lambda: self.clock_s)
        self.pending.append(pending)
        return pending

    def send(self, target: str, verb: str, body: bytes) -> None:
        self.calls.append(("send", target, verb, json.loads(body)))

    def leave_seat(self, robot: str, cause: str) -> None:
        self.calls.append(("leave", robot, cause))
        self.live = self.live - {robot}

    def join_seat(self, robot: str, cause: str) -> None:
        self.calls.append(("join", robot, cause))
        self.live = self.live | {robot}

    def await_tokens(self, wanted: dict[str, bool], timeout_s: float) -> set[str]:
        self.calls.append(("await", dict(wanted)))
        return set(wanted) if self.tokens_seen else set()

    def token_up(self, robot: str) -> bool:
        return robot in self.tokens_up

    def checkpoint_now(self) -> bool:
        self.calls.append(("checkpoint",))
        return True

    def hold(self, timeout_s: float) -> None:
        self.calls.append(("hold",))

    def record(self, kind: EventKind, subject: str | None, detail: dict[str, Any]) -> RunEvent:
        event = RunEvent(t_s=self.tick / 100, kind=kind, subject=subject, detail=detail)
        self.events.append(event)
        return event


def _hub(port: FakePort) -> FaultHub:
    return FaultHub(NAMES, port)


def _body(**fault: Any) -> bytes:
    return json.dumps(fault).encode()


OK = b'{"ok": true}'


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        (b"{not json", AdminRefusal.NOT_JSON),
        (b"", AdminRefusal.NOT_JSON),
        (_body(fault="warp", robot="robot1"), AdminRefusal.INVALID_REQUEST),
        (_body(fault="net"), AdminRefusal.INVALID_REQUEST),
        (_body(fault="pwm_stuck", robot="robot1", wheel=7, duty=0.5), AdminRefusal.INVALID_REQUEST),
        (_body(fault="net", robot="robot9", loss=0.5), AdminRefusal.UNKNOWN_ROBOT),
        (_body(fault="partition", robots=["robot1", "ghost"]), AdminRefusal.UNKNOWN_ROBOT),
        (_body(fault="fix_cut", robot="robot4"), AdminRefusal.UNKNOWN_ROBOT),
        (_body(fault="kill", process="robot4"), AdminRefusal.UNKNOWN_PROCESS),
        # Before, both were taken: a robot named twice, and a partition that cuts nobody off.
        (_body(fault="partition", robots=["robot1", "robot1"]), AdminRefusal.INVALID_REQUEST),
        (_body(fault="partition", robots=list(NAMES)), AdminRefusal.INVALID_REQUEST),
        # Before, pydantic took true for 1: a 1 ms tick_slow, a 1 ms latency.
        (_body(fault="tick_slow", robot="robot1", extra_ms=True), AdminRefusal.INVALID_REQUEST),
        (_body(fault="net", latency_ms=True), AdminRefusal.INVALID_REQUEST),
    ],
)
def test_a_bad_fault_is_refused_with_its_reason_recorded_and_changes_nothing(
    body: bytes, reason: AdminRefusal
) -> None:
    port = FakePort()
    reply = _hub(port).request(body)
    assert isinstance(reply, AdminError) and reply.reason == reason, reply
    assert port.calls == []
    assert [(e.kind, e.detail["reason"]) for e in port.events] == [("fault_refused", reason)]


def test_a_network_fault_is_applied_by_the_world_and_recorded() -> None:
    port = FakePort()
    reply = _hub(port).request(_body(fault="partition", robots=["robot3"]))
    assert isinstance(reply, FaultReply)
    assert port.calls == [("network", "partition")]
    assert reply.event == port.events[0]
    assert reply.event.kind == "fault_injected" and reply.event.subject == "robot3"
    assert reply.event.detail == {
        "fault": {"fault": "partition", "robots": ["robot3"]},
        "source": "admin",
        "tick": 1500,
    }


def test_a_register_fault_goes_to_the_robots_verb_and_its_refusal_is_surfaced() -> None:
    port = FakePort()
    port.answers[("robot2", "fault")] = AdminError(
        error="unknown admin verb 'fault'", reason=AdminRefusal.UNKNOWN_VERB
    ).to_json_bytes()
    body = _body(fault="encoder_stuck", robot="robot2", wheel=1)
    reply = _hub(port).request(body)
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNKNOWN_VERB
    assert "robot2 refused" in reply.error
    assert port.calls == [("ask", "robot2", "fault", json.loads(body))]
    assert port.events[0].kind == "fault_refused"

    port.answers[("robot2", "fault")] = b'{"ok": true, "robot": "robot2", "active": []}'
    reply = _hub(port).request(body)
    assert isinstance(reply, FaultReply) and reply.reply == {
        "ok": True,
        "robot": "robot2",
        "active": [],
    }
    assert port.events[-1].kind == "fault_injected"


def test_a_register_fault_on_a_robot_that_is_down_is_refused_without_asking() -> None:
    port = FakePort(live=frozenset({"robot1"}))
    reply = _hub(port).request(_body(fault="sonar_no_echo", robot="robot3"))
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNREACHABLE
    assert port.calls == []


def test_lockstep_kill_drops_the_seat_at_the_tick_and_holds_for_the_tokens_end() -> None:
    port = FakePort()
    port.answers[("launcher", "kill")] = b'{"ok": true, "killed": true}'
    hub = _hub(port)
    reply = hub.inject(
        FAULT_ADAPTER.validate_python({"fault": "kill", "process": "robot3"}), "schedule"
    )
    assert isinstance(reply, FaultReply)
    assert port.calls == [
        ("ask", "launcher", "kill", {"process": "robot3"}),
        ("leave", "robot3", "kill"),
    ]
    hub.settle()
    assert port.calls[-1] == ("await", {"robot3": False})
    assert [e.kind for e in port.events] == ["fault_injected"]  # robot_down: the port's record
    assert port.events[0].detail["source"] == "schedule"


def test_lockstep_restart_holds_the_tick_until_the_new_token_then_joins_it_there() -> None:
    port = FakePort(live=frozenset({"robot1", "robot2"}))
    port.answers[("launcher", "restart")] = b'{"ok": true, "restarted": "robot3", "pid": 7}'
    hub = _hub(port)
    hub.request(_body(fault="restart", process="robot3"))
    assert port.calls == [("ask", "launcher", "restart", {"process": "robot3"})]
    hub.settle()
    assert port.calls[1:] == [("await", {"robot3": True}), ("join", "robot3", "restart")]
    hub.settle()  # nothing left to hold for
    assert len(port.calls) == 3


def test_a_restart_whose_token_never_comes_does_not_join() -> None:
    port = FakePort(live=frozenset({"robot1", "robot2"}), tokens_seen=False)
    port.answers[("launcher", "restart")] = OK
    hub = _hub(port)
    hub.request(_body(fault="restart", process="robot3"))
    hub.settle()
    assert not any(call[0] == "join" for call in port.calls)


def test_in_real_time_process_faults_are_forwarded_and_liveliness_tells_the_rest() -> None:
    port = FakePort(lockstep=False)
    hub = _hub(port)
    deferred = hub.request(_body(fault="stop", process="robot2"))
    assert isinstance(deferred, DeferredAnswer)
    hub.settle()
    port.pending[0].on_answer(OK)
    port.pending[0].on_end()
    hub.poll()
    assert isinstance(deferred.answer, FaultReply)
    assert port.calls == [("ask_later", "launcher", "stop", {"process": "robot2"})]


def test_in_real_time_a_forward_holds_nothing_and_is_answered_when_its_answer_comes() -> None:
    """Before, the hub waited for the robot's answer inside the world's tick boundary: a
    frozen robot held every robot's sense messages back for up to 5 s."""
    port = FakePort(lockstep=False)
    hub = _hub(port)
    sent: list[BaseModel] = []
    deferred = hub.request(_body(fault="encoder_stuck", robot="robot2", wheel=1))
    assert isinstance(deferred, DeferredAnswer)
    deferred.bind(sent.append)
    assert port.calls == [
        ("ask_later", "robot2", "fault", {"fault": "encoder_stuck", "robot": "robot2", "wheel": 1})
    ]
    for _ in range(3):  # ticks go by: nothing recorded, nothing answered yet
        hub.poll()
    assert sent == [] and port.events == [] and hub.forwards_waiting == 1
    port.tick += 7
    port.pending[0].on_answer(b'{"ok": true, "robot": "robot2", "active": []}')
    hub.poll()
    assert hub.forwards_waiting == 0
    assert len(sent) == 1 and isinstance(sent[0], FaultReply)
    assert [(e.kind, e.detail["tick"]) for e in port.events] == [("fault_injected", 1507)]


@pytest.mark.parametrize("lockstep", [True, False])
def test_a_forward_goes_with_the_deadline_of_the_request_that_asked_for_it(lockstep: bool) -> None:
    """Before, the world forwarded with a 5 s time-out of its own whatever the `swarm fault`
    command waited: a robot could carry out a fault its sender had been told had no answer."""
    port = FakePort(lockstep=lockstep)
    port.answers[("robot2", "fault")] = OK
    hub = _hub(port)
    hub.request(_body(fault="fix_cut", robot="robot2"), reply_by_unix_ns=123_456_789)
    hub.inject(FAULT_ADAPTER.validate_python({"fault": "fix_cut", "robot": "robot3"}), "schedule")
    assert port.reply_by == [123_456_789, None]


def test_in_real_time_a_forward_nobody_answers_is_refused_once_its_time_is_out() -> None:
    port = FakePort(lockstep=False)
    hub = _hub(port)
    sent: list[BaseModel] = []
    deferred = hub.request(_body(fault="sonar_no_echo", robot="robot3"))
    assert isinstance(deferred, DeferredAnswer)
    deferred.bind(sent.append)
    port.clock_s = FORWARD_TIMEOUT_S
    hub.poll()
    assert sent == []  # Zenoh ends the request itself; a second more before giving up
    port.clock_s = FORWARD_TIMEOUT_S + 1.0
    hub.poll()
    assert len(sent) == 1 and isinstance(sent[0], AdminError)
    assert sent[0].reason == AdminRefusal.UNREACHABLE
    assert sent[0].error == "robot3 did not answer (gave up after 6.0 s)"
    assert [e.kind for e in port.events] == ["fault_refused"]


def test_in_real_time_a_forward_that_ends_without_an_answer_is_refused_at_once() -> None:
    port = FakePort(lockstep=False)
    hub = _hub(port)
    deferred = hub.inject(
        FAULT_ADAPTER.validate_python({"fault": "kill", "process": "robot3"}), "schedule"
    )
    assert isinstance(deferred, DeferredAnswer)
    port.clock_s = 1.0
    port.pending[0].on_end()  # the router closed the frozen robot's session: no answer
    hub.poll()
    assert isinstance(deferred.answer, AdminError)
    assert deferred.answer.error == "launcher did not answer (gave up after 1.0 s)"
    assert port.events[0].detail["source"] == "schedule"


def test_lockstep_stop_and_cont_leave_and_join_at_their_ticks() -> None:
    port = FakePort()
    port.answers[("launcher", "stop")] = OK
    port.answers[("launcher", "cont")] = OK
    hub = _hub(port)
    hub.request(_body(fault="stop", process="robot2"))
    hub.request(_body(fault="cont", process="robot2"))
    hub.settle()
    assert [c for c in port.calls if c[0] in ("leave", "join")] == [
        ("leave", "robot2", "stop"),
        ("join", "robot2", "cont"),
    ]


def test_lockstep_cont_after_the_lease_ran_out_joins_once_the_token_is_back() -> None:
    port = FakePort(tokens_up=frozenset({"robot1", "robot3"}))
    port.answers[("launcher", "stop")] = OK
    port.answers[("launcher", "cont")] = OK
    hub = _hub(port)
    hub.request(_body(fault="stop", process="robot2"))
    hub.request(_body(fault="cont", process="robot2"))
    assert ("join", "robot2", "cont") not in port.calls  # its token is gone: not yet
    hub.settle()
    assert port.calls[-2:] == [("await", {"robot2": True}), ("join", "robot2", "cont")]


def test_a_launcher_that_does_not_answer_or_refuses_is_a_refusal() -> None:
    port = FakePort()
    reply = _hub(port).request(_body(fault="cont", process="router"))
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNREACHABLE
    assert reply.error == "launcher did not answer"
    port.answers[("launcher", "kill")] = AdminError(
        error="no process 'dashboard'", reason=AdminRefusal.UNKNOWN_PROCESS
    ).to_json_bytes()
    reply = _hub(port).request(_body(fault="kill", process="dashboard"))
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNKNOWN_PROCESS
    assert [e.kind for e in port.events] == ["fault_refused", "fault_refused"]
    assert not any(c[0] in ("leave", "join") for c in port.calls)


def test_restarting_the_world_records_and_checkpoints_before_the_launcher_is_asked() -> None:
    port = FakePort()
    hub = _hub(port)
    reply = hub.inject(
        FAULT_ADAPTER.validate_python({"fault": "restart", "process": "world"}), "schedule"
    )
    assert isinstance(reply, FaultReply) and reply.event.kind == "fault_injected"
    assert port.calls == [("checkpoint",), ("send", "launcher", "restart", {"process": "world"})]
    hub.settle()
    # Still alive after the hold: the launcher did not do it.
    assert port.calls[-1] == ("hold",)
    assert [(e.kind, e.detail.get("reason")) for e in port.events] == [
        ("fault_injected", None),
        ("fault_refused", AdminRefusal.UNREACHABLE),
    ]


def test_killing_the_router_is_recorded_and_sent_without_waiting_for_an_answer() -> None:
    """The answer would come back through the router."""
    port = FakePort()
    hub = _hub(port)
    reply = hub.request(_body(fault="kill", process="router"))
    assert isinstance(reply, FaultReply) and reply.event.subject == "router"
    hub.settle()
    assert port.calls == [("send", "launcher", "kill", {"process": "router"})]
    assert [e.kind for e in port.events] == ["fault_injected"]


def test_stopping_the_world_is_recorded_and_sent_without_a_checkpoint() -> None:
    port = FakePort()
    hub = _hub(port)
    hub.request(_body(fault="stop", process="world"))
    hub.settle()
    assert port.calls == [("send", "launcher", "stop", {"process": "world"})]


# -- the world process's part, without a network -------------------------------------------


def _world(out: Path, scenario_path: Path, lockstep: bool = True) -> WorldProcess:
    config = WorldConfig(scenario=scenario_path, out_dir=out, lockstep=lockstep)
    return WorldProcess(config, load_scenario(scenario_path))


def _campaign(tmp_path: Path, faults: list[dict[str, Any]]) -> Path:
    text = PAPER.read_text().replace("name: paper", "name: campaign")
    path = tmp_path / "campaign.yaml"
    path.write_text(text + "\nfaults:\n" + "".join(f"  - {json.dumps(f)}\n" for f in faults))
    return path


def _step(world: WorldProcess, ticks: int) -> None:
    """Lockstep ticks with nobody up: the boundary, then the physics."""
    for _ in range(ticks):
        world._tick_boundary()
        world.engine.advance(np.zeros((3, 4)), world.period_ns)
        world.barrier.advance()


def test_a_campaign_runs_at_its_ticks_and_a_resumed_world_replays_its_file(tmp_path: Path) -> None:
    scenario = _campaign(
        tmp_path,
        [
            {"at_s": 0.05, "fault": {"fault": "partition", "robots": ["robot3"]}},
            {"at_s": 0.2, "fault": {"fault": "net", "robot": "robot1", "loss": 0.5}},
            {"at_s": 0.3, "fault": {"fault": "heal"}},
        ],
    )
    world = _world(tmp_path / "run", scenario)
    _step(world, 10)
    state = world.checkpoint_state()
    assert state["faults"] == {"cursor": 1, "events": 1}
    assert world.engine.network.cut_links() == [("robot1", "robot3"), ("robot2", "robot3")]
    assert world.checkpoints is not None
    world.checkpoints.save(world.tick, state)
    _step(world, 30)
    events = world.event_log.events
    assert [(e.t_s, e.detail["tick"], e.detail["fault"]["fault"]) for e in events] == [
        (0.05, 5, "partition"),
        (0.2, 20, "net"),
        (0.3, 30, "heal"),
    ]
    assert not world.engine.network.active
    first_run = (tmp_path / "run" / "events.jsonl").read_bytes()

    resumed = _world(tmp_path / "run", scenario)
    assert resumed.tick == 10 and resumed.schedule.cursor == 1
    assert resumed.engine.network.cut_links() == [("robot1", "robot3"), ("robot2", "robot3")]
    _step(resumed, 30)
    lines = (tmp_path / "run" / "events.jsonl").read_bytes().splitlines(keepends=True)
    assert [json.loads(x)["kind"] for x in lines] == [
        "fault_injected",
        "world_resumed",
        "fault_injected",
        "fault_injected",
    ]
    # After the resume line, what the first world wrote after its checkpoint, again.
    original = first_run.splitlines(keepends=True)
    assert lines[0] == original[0] and lines[2:] == original[1:]
    summary = resumed.summary()["run_events"]
    assert summary["counts"]["fault_injected"] == 3
    assert summary["counts"]["world_resumed"] == 1


def test_the_worlds_fault_verb_waits_for_a_tick_boundary(tmp_path: Path) -> None:
    world = _world(tmp_path / "run", PAPER)
    handlers = world.admin_handlers()
    reply = handlers["fault"](_body(fault="net", loss=1.0))
    assert isinstance(reply, FaultReply)
    assert world.engine.params.link_table is not None
    # With no process to forward to, a process fault cannot be done.
    refused = handlers["fault"](_body(fault="kill", process="robot2"))
    assert isinstance(refused, AdminError) and refused.reason == AdminRefusal.UNREACHABLE
    lines = (tmp_path / "run" / "events.jsonl").read_text().splitlines()
    assert [json.loads(x)["kind"] for x in lines] == ["fault_injected", "fault_refused"]


# -- summary.json ---------------------------------------------------------------------------


def test_the_summary_counts_every_kind_and_times_failovers_and_rejoins() -> None:
    kill = {"fault": {"fault": "kill", "process": "robot1"}}
    events = [
        RunEvent(t_s=25.0, kind="fault_injected", subject="robot1", detail=kill),
        RunEvent(t_s=25.0, kind="robot_down", subject="robot1"),
        RunEvent(
            t_s=25.53, kind="leader_change", subject="robot2", detail={"from": "robot1", "term": 1}
        ),
        RunEvent(
            t_s=40.0,
            kind="fault_injected",
            subject="robot1",
            detail={"fault": {"fault": "restart"}},
        ),
        RunEvent(t_s=40.0, kind="robot_up", subject="robot1"),
        RunEvent(t_s=41.0, kind="robot_up", subject="robot3"),  # never seen down
        RunEvent(
            t_s=50.0, kind="leader_change", subject="robot3", detail={"from": "robot2", "term": 2}
        ),
    ]
    summary = summarise_events(events)
    assert summary["counts"] == {
        "fault_injected": 2,
        "fault_refused": 0,
        "robot_down": 1,
        "robot_up": 2,
        "leader_change": 2,
        "world_resumed": 0,
        "collision": 0,
    }
    assert summary["faults_injected"] == {"kill": 1, "restart": 1}
    assert summary["failovers"] == [
        {"t_s": 25.53, "from": "robot1", "to": "robot2", "term": 1, "after_leader_down_s": 0.53},
        {"t_s": 50.0, "from": "robot2", "to": "robot3", "term": 2, "after_leader_down_s": None},
    ]
    assert summary["rejoins"] == [
        {"robot": "robot1", "down_t_s": 25.0, "up_t_s": 40.0, "down_for_s": 15.0}
    ]


def test_the_network_faults_in_effect_are_reported_grouped_by_what_they_set() -> None:
    """Before, `swarm net get` and the world's status showed the running profile alone, while
    a `fault net` override dropped nine frames in ten."""
    faults = NetworkFaults(NAMES)
    assert faults.report() is None
    faults.apply(NetFault(fault="net", robot="robot3", loss=0.9))
    faults.apply(NetFault(fault="net", link=("robot1", "robot2"), latency_ms=40.0))
    faults.apply(PartitionFault(fault="partition", robots=["robot1"]))
    report = faults.report()
    assert report is not None
    assert [o.model_dump(exclude_none=True) for o in report.overrides] == [
        {"links": (("robot1", "robot2"),), "latency_ms": 40.0},
        {"links": (("robot1", "robot3"), ("robot2", "robot3")), "loss": 0.9},
    ]
    assert report.cut_links == (("robot1", "robot2"), ("robot1", "robot3"))
    faults.apply(NetFault(fault="net", burst=BurstLoss(good_to_bad=0.1, bad_to_good=0.5)))
    report = faults.report()
    assert report is not None and len(report.overrides) == 2
    assert all(o.burst == BurstLoss(good_to_bad=0.1, bad_to_good=0.5) for o in report.overrides)
    faults.apply(HealFault(fault="heal"))
    assert faults.report() is None

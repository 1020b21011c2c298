"""The dashboard's event timeline: each run event of the world (swarm_config/faults.py
`RunEvent`) becomes a line of the event log and a marker on its kind's row, at its own
simulation time; events already in `<out>/events.jsonl` are logged too, each event once; a
campaign run by `swarm up` with its dashboard lands in dashboard.rrd (slow)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import rerun as rr

from services.dashboard import entities
from services.dashboard.live import EVENTS_FILE, DashboardConfig, DashboardService
from services.dashboard.scene import (
    EVENT_KINDS,
    EVENT_ROWS,
    EVENT_STYLES,
    LogRecord,
    SwarmScene,
    Update,
    describe_event,
)
from swarm_config.credentials import DASHBOARD, generate_credential_set
from swarm_config.faults import RunEvent
from swarm_config.scenario import Scenario, load_scenario
from tests.dashboard.conftest import free_port, read_recording, start

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"

KILL_LEADER = RunEvent(
    t_s=25.0,
    kind="fault_injected",
    subject="robot1",
    detail={"fault": {"fault": "kill", "process": "robot1"}, "source": "schedule"},
)
LEADER_CHANGE = RunEvent(
    t_s=25.55, kind="leader_change", subject="robot2", detail={"term": 1, "from": "robot1"}
)
DOWN = RunEvent(t_s=25.01, kind="robot_down", subject="robot1")
PWM_STUCK = RunEvent(
    t_s=3.2,
    kind="fault_injected",
    subject="robot2",
    detail={
        "fault": {"fault": "pwm_stuck", "robot": "robot2", "wheel": 0, "duty": 0.5},
        "source": "admin",
    },
)
REFUSED = RunEvent(
    t_s=4.0,
    kind="fault_refused",
    detail={"fault": {"fault": "fix_cut", "robot": "robot9"}, "reason": "unknown_robot"},
)


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario(PAPER)


def _dashboard(scenario: Scenario, out_dir: Path | None) -> DashboardService:
    credentials = generate_credential_set("lab", scenario.robot_names).for_identity(DASHBOARD)
    config = DashboardConfig(scenario=PAPER, credentials=credentials, out_dir=out_dir)
    return DashboardService(config, scenario)


def _record(update: Update, path: str) -> LogRecord:
    (match,) = [r for r in update.records if r.entity_path == path]
    return match


def _text(update: Update) -> tuple[str, str]:
    log = next(a for a in _record(update, entities.EVENTS).archetypes if isinstance(a, rr.TextLog))
    (text,) = log.text.as_arrow_array().to_pylist()
    (level,) = log.level.as_arrow_array().to_pylist()
    return str(text), str(level)


def _marker_row(update: Update, kind: str) -> float:
    record = _record(update, entities.event_marker(kind))
    scalars = next(a for a in record.archetypes if isinstance(a, rr.Scalars))
    (value,) = scalars.scalars.as_arrow_array().to_pylist()
    return float(value)


def test_an_event_is_a_log_line_and_a_marker_at_its_own_sim_time(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    update = scene.on_event(KILL_LEADER)
    assert update.t_s == 25.0
    assert update.paths() == {entities.EVENTS, entities.event_marker("fault_injected")}
    assert _text(update) == ("t=25.00 s fault_injected kill robot1 source=schedule", "WARN")
    assert _marker_row(update, "fault_injected") == EVENT_ROWS["fault_injected"]
    # The scene's clock is not moved by an event: the map stays at the newest truth.
    assert scene.last_t_s is None


def test_every_kind_has_its_own_row_and_style(scenario: Scenario) -> None:
    assert sorted(EVENT_ROWS.values()) == list(range(len(EVENT_KINDS)))
    assert set(EVENT_STYLES) == set(EVENT_KINDS)
    assert len({s.marker for s in EVENT_STYLES.values()}) == len(EVENT_KINDS)
    static = SwarmScene(scenario).static_update()
    for kind in EVENT_KINDS:
        style = _record(static, entities.event_marker(kind))
        assert style.static
        assert any(isinstance(a, rr.SeriesPoints) for a in style.archetypes)
    scene = SwarmScene(scenario)
    rows = {
        kind: _marker_row(scene.on_event(RunEvent(t_s=1.0, kind=kind, subject="robot2")), kind)
        for kind in EVENT_KINDS
    }
    assert len(set(rows.values())) == len(EVENT_KINDS)


@pytest.mark.parametrize(
    ("event", "text"),
    [
        (KILL_LEADER, "fault_injected kill robot1 source=schedule"),
        (PWM_STUCK, "fault_injected pwm_stuck robot2 wheel=0 duty=0.5 source=admin"),
        (REFUSED, "fault_refused fix_cut robot9 reason=unknown_robot"),
        (LEADER_CHANGE, "leader_change robot2 from=robot1 term=1"),
        (DOWN, "robot_down robot1"),
        (
            RunEvent(
                t_s=1.0,
                kind="fault_injected",
                subject="robot1,robot3",
                detail={"fault": {"fault": "net", "link": ["robot1", "robot3"], "loss": 0.3}},
            ),
            "fault_injected net robot1 robot3 loss=0.3",
        ),
        (
            RunEvent(t_s=1.0, kind="fault_refused", detail={"fault": {"fault": "melt"}}),
            'fault_refused {"fault":"melt"}',
        ),
        (
            RunEvent(t_s=9.0, kind="world_resumed", detail={"checkpoint_t_s": 8.5}),
            "world_resumed checkpoint_t_s=8.5",
        ),
    ],
)
def test_event_lines_say_what_happened_to_whom(event: RunEvent, text: str) -> None:
    assert describe_event(event) == text


def _write_events(path: Path, lines: list[str]) -> None:
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")


def test_events_already_in_the_run_directory_are_logged_once(
    scenario: Scenario, tmp_path: Path
) -> None:
    _write_events(
        tmp_path / EVENTS_FILE,
        [
            KILL_LEADER.model_dump_json(),
            "not json",
            '{"t_s": 1.0}',
            "",
            DOWN.model_dump_json(),
        ],
    )
    dashboard = _dashboard(scenario, tmp_path)
    updates = dashboard.events_from_file()
    assert [u.t_s for u in updates] == [KILL_LEADER.t_s, DOWN.t_s]
    assert dashboard.counts["event"] == 2
    assert dict(dashboard.rejected) == {"not_json": 1, "does_not_fit": 1}
    # Heard live as well: logged once; a new one is logged.
    assert dashboard.event_update(KILL_LEADER.model_dump_json().encode()) is None
    live = dashboard.event_update(LEADER_CHANGE.model_dump_json().encode())
    assert isinstance(live, Update) and live.t_s == LEADER_CHANGE.t_s
    # Read again while the world is half way through a line: nothing new, nothing rejected.
    line = PWM_STUCK.model_dump_json() + "\n"
    with (tmp_path / EVENTS_FILE).open("a", encoding="utf-8") as events:
        events.write(line[:20])
    assert dashboard.events_from_file() == []
    # Once the line is whole, it counts, once.
    with (tmp_path / EVENTS_FILE).open("a", encoding="utf-8") as events:
        events.write(line[20:])
    assert [u.t_s for u in dashboard.events_from_file()] == [PWM_STUCK.t_s]
    assert dashboard.counts["event"] == 3
    assert dict(dashboard.rejected) == {"not_json": 1, "does_not_fit": 1}


def test_no_run_directory_or_no_file_means_no_events(scenario: Scenario, tmp_path: Path) -> None:
    assert _dashboard(scenario, None).events_from_file() == []
    assert _dashboard(scenario, tmp_path).events_from_file() == []


def test_event_payloads_that_do_not_fit_are_rejected_and_unknown_fields_ignored(
    scenario: Scenario,
) -> None:
    dashboard = _dashboard(scenario, None)
    assert dashboard.event_update(b"\xff\xfe") == "not_json"
    assert dashboard.event_update(b"[1, 2]") == "does_not_fit"
    assert dashboard.event_update(b'{"t_s": 1.0, "kind": "exploded"}') == "does_not_fit"
    assert dashboard.event_update(b'{"t_s": 1e39, "kind": "robot_up"}') == "out_of_range"
    newer = {**json.loads(DOWN.model_dump_json()), "epoch": 3}
    update = dashboard.event_update(json.dumps(newer).encode())
    assert isinstance(update, Update) and _text(update)[0] == "t=25.01 s robot_down robot1"


def test_events_land_in_the_recording_at_their_sim_times(
    scenario: Scenario, tmp_path: Path
) -> None:
    dashboard = _dashboard(scenario, None)
    path = tmp_path / "events.rrd"
    recording = rr.RecordingStream("swarm-cps-test")
    recording.save(str(path))
    dashboard._log(recording, dashboard.scene.static_update())
    for event in (PWM_STUCK, KILL_LEADER, DOWN, LEADER_CHANGE):
        dashboard._log(recording, dashboard.scene.on_event(event))
    recording.flush(timeout_sec=10.0)
    recording.disconnect()
    recorded = read_recording(path)
    log = recorded[f"/{entities.EVENTS}"]
    texts = [t for _, (t,) in log.values("TextLog:text")]
    assert texts == [
        "t=3.20 s fault_injected pwm_stuck robot2 wheel=0 duty=0.5 source=admin",
        "t=25.00 s fault_injected kill robot1 source=schedule",
        "t=25.01 s robot_down robot1",
        "t=25.55 s leader_change robot2 from=robot1 term=1",
    ]
    injected = recorded[f"/{entities.event_marker('fault_injected')}"]
    assert [(t, v) for t, v in injected.values("Scalars:scalars")] == [
        (3.2, [EVENT_ROWS["fault_injected"]]),
        (25.0, [EVENT_ROWS["fault_injected"]]),
    ]
    assert f"/{entities.event_marker('leader_change')}" in recorded


CAMPAIGN = ROOT / "configs" / "campaigns" / "follower-restart.yaml"


@pytest.mark.slow
def test_a_campaigns_events_reach_the_recording_of_swarm_ups_dashboard(tmp_path: Path) -> None:
    """`swarm up --lockstep` of a campaign with its dashboard: every event the world records
    in events.jsonl is in dashboard.rrd, on the event log and the timeline, at its time."""
    out = tmp_path / "run"
    argv = ["-m", "services.cli.main", "up", "--lockstep", "--scenario", str(CAMPAIGN)]
    argv += ["--duration", "30", "--out", str(out), "--port", str(free_port())]
    argv += ["--web-port", str(free_port()), "--grpc-port", str(free_port())]
    swarm = start("swarm", argv, tmp_path / "logs")
    try:
        assert swarm.process.wait(timeout=300) == 0, swarm.output()
    finally:
        swarm.shut_down()
    recorded_events = [
        RunEvent.model_validate_json(line)
        for line in (out / EVENTS_FILE).read_text(encoding="utf-8").splitlines()
    ]
    assert [(e.t_s, e.kind) for e in recorded_events] == [
        (15.0, "fault_injected"),
        (15.0, "robot_down"),
        (25.0, "fault_injected"),
        (25.0, "robot_up"),
    ]
    recording = read_recording(out / "dashboard.rrd")
    lines = [(t, text) for t, (text,) in recording[f"/{entities.EVENTS}"].values("TextLog:text")]
    for event in recorded_events:
        assert (event.t_s, f"t={event.t_s:.2f} s {describe_event(event)}") in lines, lines
    for kind in ("fault_injected", "robot_down", "robot_up"):
        marked = recording[f"/{entities.event_marker(kind)}"].values("Scalars:scalars")
        expected = [e.t_s for e in recorded_events if e.kind == kind]
        assert [t for t, _ in marked] == expected, (kind, marked)

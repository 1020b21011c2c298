"""The pure core of the dashboard: messages in, Rerun records out (no network, no viewer)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from robot_firmware.control.formation import follower_slot_in_world
from robot_firmware.net.messages import TelemetryMessage, TruthMessage, parse_message
from services.dashboard import entities
from services.dashboard.blueprint import default_blueprint
from services.dashboard.live import keep_previous_recording, viewer_url
from services.dashboard.scene import (
    DOWN_COLOUR,
    ROBOT_COLOURS,
    TELEMETRY_LEAD_MAX_S,
    LogRecord,
    SwarmScene,
    Update,
)
from swarm_config.scenario import Scenario, load_scenario
from world.metrics import FormationLayout

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario(ROOT / "configs" / "scenarios" / "paper.yaml")


def _truth(
    scenario: Scenario,
    t_s: float,
    follower_offset_m: float = 0.0,
    alive: dict[str, bool] | None = None,
    radio: dict[str, object] | None = None,
) -> TruthMessage:
    """Leader on its reference, followers on their slots (plus an offset along x)."""
    reference, _ = scenario.trajectory.build().evaluate(t_s)
    leader = np.asarray(reference, dtype=np.float64)
    layout = FormationLayout.from_scenario(scenario)
    robots: dict[str, object] = {}
    for i, name in enumerate(scenario.robot_names):
        if i == layout.leader_index:
            pose = leader
        else:
            slot = follower_slot_in_world(
                leader, layout.slot_distance_m[i], layout.slot_angle_rad[i]
            )
            pose = np.array([slot[0] + follower_offset_m, slot[1], leader[2]])
        robots[name] = {
            "pose": [float(v) for v in pose],
            "alive": True if alive is None else alive.get(name, True),
        }
    payload = {"t_s": t_s, "tick": 0, "robots": robots, "reference": [float(v) for v in leader]}
    if radio is not None:
        payload["radio"] = radio
    message = parse_message(TruthMessage, json.dumps(payload).encode())
    assert message is not None
    return message


def _record(update: Update | None, path: str) -> LogRecord:
    assert update is not None
    matches = [r for r in update.records if r.entity_path == path]
    assert len(matches) == 1, (path, [r.entity_path for r in update.records])
    return matches[0]


def _archetype(record: LogRecord, kind: type) -> object:
    return next(a for a in record.archetypes if isinstance(a, kind))


def _scalars(update: Update | None, path: str) -> list[float]:
    scalars = _archetype(_record(update, path), rr.Scalars)
    return [float(v) for v in scalars.scalars.as_arrow_array().to_pylist()]


def test_formation_errors_are_distances_from_the_slots(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    on_slots = scene.on_truth(_truth(scenario, 3.0))
    assert _scalars(on_slots, entities.FORMATION_ERRORS) == pytest.approx([0.0, 0.0], abs=1e-9)
    assert _scalars(on_slots, entities.LEADER_ERRORS) == pytest.approx([0.0, 0.0], abs=1e-9)
    displaced = scene.on_truth(_truth(scenario, 3.05, follower_offset_m=0.1))
    assert _scalars(displaced, entities.FORMATION_ERRORS) == pytest.approx([0.1, 0.1])


def test_leader_is_labelled_and_a_robot_that_is_down_is_grey(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    update = scene.on_truth(_truth(scenario, 1.0, alive={"robot3": False}))
    labels = {}
    colours = {}
    for name in scenario.robot_names:
        body = _archetype(_record(update, entities.robot(name)), rr.Points2D)
        labels[name] = body.labels.as_arrow_array().to_pylist()[0]
        colours[name] = body.colors.as_arrow_array().to_pylist()[0]
    assert labels == {"robot1": "robot1 · leader", "robot2": "robot2", "robot3": "robot3 · down"}

    def rgba(rgb: tuple[int, int, int]) -> int:
        return (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | 0xFF

    assert colours["robot1"] == rgba(ROBOT_COLOURS[0])
    assert colours["robot2"] == rgba(ROBOT_COLOURS[1])
    assert colours["robot3"] == rgba(DOWN_COLOUR)


def test_recent_delivery_ratio_covers_the_last_second_only(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    ratios = []
    # 100 frames per 0.5 s: all delivered for 2 s, then half of them.
    delivered = frames = 0
    for k in range(9):
        t_s = 0.5 * k
        radio = {"frames": frames, "delivered": delivered, "delivery_ratio": None}
        ratios.append(
            _scalars(scene.on_truth(_truth(scenario, t_s, radio=radio)), "radio/delivery_ratio")
        )
        frames += 100
        delivered += 100 if t_s < 2.0 else 50
    assert math.isnan(ratios[0][1])
    assert ratios[3][1] == pytest.approx(1.0)
    assert ratios[-1][1] == pytest.approx(0.5)


def test_trail_keeps_recent_poses_and_restarts_when_the_world_does(scenario: Scenario) -> None:
    scene = SwarmScene(scenario, trail_duration_s=2.0, trail_period_s=0.0)
    update = None
    for k in range(80):
        update = scene.on_truth(_truth(scenario, 0.05 * k))
    strip = _archetype(_record(update, entities.robot("robot1")), rr.LineStrips2D)
    points = strip.strips.as_arrow_array().to_pylist()[0]
    assert 19 <= len(points) <= 22  # 2 s at one point per 0.1 s, plus the pose now
    after_restart = scene.on_truth(_truth(scenario, 0.0))
    strip = _archetype(_record(after_restart, entities.robot("robot1")), rr.LineStrips2D)
    assert len(strip.strips.as_arrow_array().to_pylist()[0]) == 1


def test_telemetry_stamped_far_past_the_world_is_not_drawn_and_moves_nothing(
    scenario: Scenario,
) -> None:
    scene = SwarmScene(scenario, trail_duration_s=2.0, trail_period_s=0.0)
    for k in range(80):
        scene.on_truth(_truth(scenario, 0.05 * k))
    newest_truth_s = 0.05 * 79

    def telemetry(t_s: float) -> TelemetryMessage:
        payload = {"robot": "robot2", "t_s": t_s, "estimate": [0.1, 0.2, 0.3]}
        message = parse_message(TelemetryMessage, json.dumps(payload).encode())
        assert message is not None
        return message

    for lie_s in (1e9, newest_truth_s + TELEMETRY_LEAD_MAX_S + 0.01):
        assert scene.ahead_of_world(lie_s)
        assert scene.on_telemetry(telemetry(lie_s)) is None
        assert scene.last_t_s == newest_truth_s
    honest = scene.on_telemetry(telemetry(newest_truth_s + 0.06))
    assert honest is not None and honest.t_s == newest_truth_s + 0.06
    # The next truth sample finds no clock jump: the trail goes on.
    update = scene.on_truth(_truth(scenario, newest_truth_s + 0.05))
    strip = _archetype(_record(update, entities.robot("robot1")), rr.LineStrips2D)
    assert len(strip.strips.as_arrow_array().to_pylist()[0]) > 15


def test_gains_come_from_telemetry_at_its_own_time(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    payload = {
        "robot": "robot2",
        "t_s": 4.25,
        "role": "follower",
        "estimate": [0.1, 0.2, 0.3],
        "kp": [6.0, 4.0, 5.0],
        "ki": [3.0, 2.0, 2.5],
        "kd": [0.15, 0.1, 0.125],
        "frames": {"accepted": 3},
    }
    telemetry = parse_message(TelemetryMessage, json.dumps(payload).encode())
    assert telemetry is not None
    update = scene.on_telemetry(telemetry)
    assert update is not None and update.t_s == 4.25
    assert _scalars(update, entities.gain("kp", "robot2")) == [6.0, 4.0, 5.0]
    assert _scalars(update, entities.gain("kd", "robot2")) == [0.15, 0.1, 0.125]
    assert entities.estimate("robot2") in update.paths()
    stranger = parse_message(TelemetryMessage, json.dumps({**payload, "robot": "robot9"}).encode())
    assert stranger is not None and scene.on_telemetry(stranger) is None
    assert scene.unknown_robots == {"robot9"}


def test_sonar_echoes_are_rays_from_the_estimated_position(scenario: Scenario) -> None:
    scene = SwarmScene(scenario)
    payload = {
        "robot": "robot1",
        "t_s": 7.5,
        "estimate": [1.0, 2.0, 0.5],
        "sonar_echoes_m": [[1.5, 2.0], [1.0, 2.75]],
    }
    telemetry = parse_message(TelemetryMessage, json.dumps(payload).encode())
    assert telemetry is not None
    sweep = _record(scene.on_telemetry(telemetry), entities.sonar("robot1"))
    rays = _archetype(sweep, rr.LineStrips2D).strips.as_arrow_array().to_pylist()
    assert [[list(p) for p in ray] for ray in rays] == [
        [[1.0, 2.0], [1.5, 2.0]],
        [[1.0, 2.0], [1.0, 2.75]],
    ]
    echoes = _archetype(sweep, rr.Points2D).positions.as_arrow_array().to_pylist()
    assert [list(p) for p in echoes] == [[1.5, 2.0], [1.0, 2.75]]

    silent = parse_message(TelemetryMessage, json.dumps({**payload, "sonar_echoes_m": []}).encode())
    assert silent is not None
    cleared = _record(scene.on_telemetry(silent), entities.sonar("robot1"))
    assert _archetype(cleared, rr.LineStrips2D).strips.as_arrow_array().to_pylist() == []

    older = parse_message(
        TelemetryMessage,
        json.dumps({k: v for k, v in payload.items() if k != "sonar_echoes_m"}).encode(),
    )
    assert older is not None
    update = scene.on_telemetry(older)
    assert update is not None and entities.sonar("robot1") not in update.paths()


def test_processes_joining_and_leaving_are_events_at_the_newest_sim_time(
    scenario: Scenario,
) -> None:
    scene = SwarmScene(scenario)
    scene.on_truth(_truth(scenario, 7.5))
    left = scene.on_liveliness("robot", "robot2", alive=False)
    joined = scene.on_liveliness("world", "world", alive=True)
    assert left.t_s == 7.5
    log = _archetype(_record(left, entities.EVENTS), rr.TextLog)
    assert log.text.as_arrow_array().to_pylist() == ["robot2 left"]
    assert log.level.as_arrow_array().to_pylist() == ["WARN"]
    log = _archetype(_record(joined, entities.EVENTS), rr.TextLog)
    assert log.text.as_arrow_array().to_pylist() == ["world joined"]


def test_payloads_that_do_not_fit_are_rejected(scenario: Scenario) -> None:
    assert parse_message(TruthMessage, b"not json") is None
    assert parse_message(TruthMessage, b'{"t_s": 1.0, "robots": {}}') is None  # no reference
    assert parse_message(TelemetryMessage, b'{"robot": "robot1"}') is None  # no t_s
    scene = SwarmScene(scenario)
    partial = parse_message(
        TruthMessage,
        json.dumps(
            {"t_s": 1.0, "robots": {"robot1": {"pose": [0, 0, 0]}}, "reference": [0, 0, 0]}
        ).encode(),
    )
    assert partial is not None and scene.on_truth(partial) is None
    assert scene.rejected_truth == 1


def test_static_layers_and_series_styles_are_static(scenario: Scenario) -> None:
    update = SwarmScene(scenario).static_update()
    assert update.t_s is None and all(r.static for r in update.records)
    paths = update.paths()
    assert {entities.MAP, entities.OBSTACLES, entities.REFERENCE_PATH} <= paths
    assert {entities.gain(g, n) for g in entities.GAIN_NAMES for n in scenario.robot_names} <= paths


def test_map_bounds_hold_the_path_the_slots_and_the_start_poses(scenario: Scenario) -> None:
    x_min, x_max, y_min, y_max = SwarmScene(scenario).map_bounds_m()
    # A 1.5 m circle with slots 1.2 m away and 0.3 m bodies: at least 3 m from the centre.
    assert x_min <= -3.0 and x_max >= 3.0 and y_min <= -3.0 and y_max >= 3.0
    assert x_max - x_min < 8.0
    blueprint = default_blueprint((x_min, x_max, y_min, y_max))
    assert blueprint is not None


def test_viewer_url_names_the_grpc_proxy_as_its_data_source() -> None:
    assert viewer_url("127.0.0.1", 9090, 9876) == (
        "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy"
    )
    assert viewer_url("lab-pc", 8080, 9000).endswith(
        "?url=rerun%2Bhttp%3A%2F%2Flab-pc%3A9000%2Fproxy"
    )


def test_a_previous_recording_is_kept_under_the_next_free_number(tmp_path: Path) -> None:
    path = tmp_path / "dashboard.rrd"
    assert keep_previous_recording(path) is None
    path.write_bytes(b"first")
    assert keep_previous_recording(path) == tmp_path / "dashboard-1.rrd"
    path.write_bytes(b"second")
    assert keep_previous_recording(path) == tmp_path / "dashboard-2.rrd"
    assert not path.exists()
    assert (tmp_path / "dashboard-1.rrd").read_bytes() == b"first"


def test_the_real_time_factor_is_logged_from_the_truths_arrival_times(scenario: Scenario) -> None:
    scene = SwarmScene(scenario, real_time_factor_window_s=5.0)
    assert entities.REAL_TIME_FACTOR in scene.static_update().paths()
    first = scene.on_truth(_truth(scenario, 10.0), received_s=100.0)
    assert first is not None and entities.REAL_TIME_FACTOR not in first.paths()  # no span yet
    factors = []
    for k in range(1, 101):  # 10 s of wall time, the world at half speed
        update = scene.on_truth(_truth(scenario, 10.0 + 0.05 * k), received_s=100.0 + 0.1 * k)
        factors.append(_scalars(update, entities.REAL_TIME_FACTOR)[0])
    assert factors[-1] == pytest.approx(0.5)
    without_arrival = scene.on_truth(_truth(scenario, 16.0))
    assert without_arrival is not None
    assert entities.REAL_TIME_FACTOR not in without_arrival.paths()

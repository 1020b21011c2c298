"""Fuzzing telemetry and truth as the dashboard reads them (services/dashboard/live.py
`update_for`: `parse_message_or_reason`, then `SwarmScene.on_truth` / `on_telemetry`).

10,000 samples of each: random bytes, random JSON, and valid messages with a field mutated
(NaN or infinity, wrong types, huge arrays, robots the scenario does not name, fields missing
or unknown).  Nothing may raise; every sample is either drawn or rejected under a named reason,
and a rejected sample leaves the scene (trails, clock, radio window) as it was.
"""

from __future__ import annotations

import copy
import random
from collections.abc import Callable
from typing import Any, Literal

import pytest

from services.dashboard.live import DashboardConfig, DashboardService
from swarm_config.credentials import DASHBOARD, generate_credential_set
from swarm_config.scenario import load_scenario
from tests.fuzz.generate import json_bytes, mutate_json, random_bytes, random_json
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.processes import PAPER, make_robot, make_world

INPUTS = 10_000
REASONS = frozenset(
    ("not_json", "does_not_fit", "non_finite", "out_of_range", "missing_robots")
    + ("unknown_robot", "wrong_sender", "ahead_of_world", "nothing_to_draw")
)


@pytest.fixture
def dashboard() -> DashboardService:
    scenario = load_scenario(PAPER)
    credentials = generate_credential_set("lab", scenario.robot_names).for_identity(DASHBOARD)
    return DashboardService(DashboardConfig(scenario=PAPER, credentials=credentials), scenario)


def _scene_state(dashboard: DashboardService) -> object:
    scene = dashboard.scene
    return (
        scene.last_t_s,
        {n: tuple(t) for n, t in scene._trails.items()},
        tuple(scene._radio.samples),
        scene._next_trail_log_s,
    )


def fuzz_samples(
    target: str,
    dashboard: DashboardService,
    kind: Literal["truth", "telemetry"],
    valid: Callable[[random.Random, int], dict[str, Any]],
    seed: int,
) -> None:
    rng = random.Random(seed)
    for i in range(INPUTS):
        roll = rng.random()
        if roll < 0.1:
            payload = random_bytes(rng, 200)
        elif roll < 0.2:
            payload = json_bytes(random_json(rng))
        elif roll < 0.9:
            payload = json_bytes(mutate_json(rng, valid(rng, i)))
        else:
            payload = json_bytes(valid(rng, i))
        before = _scene_state(dashboard)
        update = dashboard.update_for(kind, payload)
        if isinstance(update, str):
            assert update in REASONS, update
            if update not in ("unknown_robot", "nothing_to_draw"):  # the scene looked at it
                assert _scene_state(dashboard) == before, (payload[:300], update)
            LEDGER.record(target, update)
        else:
            assert update.records
            LEDGER.record(target, ACCEPTED)
    assert LEDGER.outcomes[target][ACCEPTED] > INPUTS // 20


def test_truth_samples(dashboard: DashboardService) -> None:
    world = make_world()
    world.barrier.join("robot1")
    template = world._status()  # a live world's poses and radio counters
    truth: dict[str, Any] = {
        "t_s": 0.0,
        "tick": 0,
        "robots": {
            n: {"pose": [0.1 * i, -0.2, 0.5], "alive": True} for i, n in enumerate(template.robots)
        },
        "reference": [0.0, 0.0, 0.0],
        "radio": template.radio.model_dump(mode="json"),
    }

    def valid(rng: random.Random, i: int) -> dict[str, Any]:
        message = copy.deepcopy(truth)
        message["t_s"] = i * 0.05
        message["tick"] = i * 5
        for robot in message["robots"].values():
            robot["pose"][0] += rng.uniform(-0.01, 0.01)
        return message

    fuzz_samples("dashboard truth", dashboard, "truth", valid, 8)


def test_telemetry_samples(dashboard: DashboardService) -> None:
    robot = make_robot("robot2")
    robot.control_tick(robot.process.period_ns)
    template = robot.process.telemetry(robot.process.period_ns).model_dump(mode="json")

    def valid(rng: random.Random, i: int) -> dict[str, Any]:
        message = copy.deepcopy(template)
        message["robot"] = rng.choice(("robot1", "robot2", "robot3"))
        message["t_s"] = i * 0.05
        return message

    fuzz_samples("dashboard telemetry", dashboard, "telemetry", valid, 9)


def test_telemetry_stamped_far_past_the_worlds_truth_is_counted_and_not_drawn(
    dashboard: DashboardService,
) -> None:
    names = dashboard.scene.names
    truth = {
        "t_s": 2.0,
        "tick": 200,
        "robots": {n: {"pose": [0.5 * i, -0.2, 0.5], "alive": True} for i, n in enumerate(names)},
        "reference": [0.0, 0.0, 0.0],
    }
    assert not isinstance(dashboard.update_for("truth", json_bytes(truth)), str)
    robot = make_robot("robot2")
    robot.control_tick(robot.process.period_ns)
    honest = robot.process.telemetry(2_000_000_000).model_dump(mode="json")
    before = _scene_state(dashboard)
    for lie_s in (1e6, 3.5):
        lie = json_bytes({**honest, "t_s": lie_s})
        assert dashboard.update_for("telemetry", lie, sender="robot2") == "ahead_of_world"
        assert _scene_state(dashboard) == before
    drawn = dashboard.update_for("telemetry", json_bytes(honest), sender="robot2")
    assert not isinstance(drawn, str) and drawn.records


def test_telemetry_naming_another_robot_than_its_key_is_not_drawn(
    dashboard: DashboardService,
) -> None:
    robot = make_robot("robot2")
    robot.control_tick(robot.process.period_ns)
    payload = robot.process.telemetry(robot.process.period_ns).to_json_bytes()
    before = _scene_state(dashboard)
    assert dashboard.update_for("telemetry", payload, sender="robot3") == "wrong_sender"
    assert _scene_state(dashboard) == before
    drawn = dashboard.update_for("telemetry", payload, sender="robot2")
    assert not isinstance(drawn, str) and drawn.records

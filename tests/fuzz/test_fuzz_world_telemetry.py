"""Fuzzing the telemetry a world process takes from the robots (world/runtime.py `_on_telemetry`,
then `_take_telemetry`, which stamps each sample in integer nanoseconds and applies it).

Telemetry is the one JSON message any robot identity may put, each on its own key
(`telemetry/<robot>`), so a robot that lies or is compromised reaches the world this way.
10,000 samples: random bytes, random JSON, valid samples with a field mutated (NaN, infinity,
1e308, wrong types: tests/fuzz/generate.py), samples naming another robot than their key, and
valid samples.  Nothing may raise; every refused sample is counted in `malformed_telemetry`
(summary.json), and a twin world fed only the accepted samples keeps the same bookkeeping:
sense drops, reported roles, loop timing and the leader the metrics follow.
"""

from __future__ import annotations

import copy
import random
from dataclasses import dataclass
from typing import Any

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import TelemetryMessage, parse_message
from tests.fuzz.generate import json_bytes, mutate_json, random_bytes, random_json
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.processes import make_robot, make_world
from world.input_budget import InputBudget
from world.runtime import WorldProcess

INPUTS = 10_000
BATCH = 50
KEYS = SwarmKeys("lab")


@dataclass(frozen=True)
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass(frozen=True)
class _Sample:
    """What `_on_telemetry` reads of a zenoh.Sample: its key and its payload."""

    key_expr: str
    payload: _Payload


def _bookkeeping(world: WorldProcess) -> object:
    metrics = world.engine.metrics
    return (
        dict(world.sense_drops),
        dict(world.reported_roles),
        {name: timing.model_dump() for name, timing in world.timing.items()},
        metrics.leader_index,
        metrics.leader_term,
    )


def test_no_telemetry_sample_the_world_refuses_changes_it() -> None:
    fed_everything, fed_valid_only = make_world(), make_world()
    names = fed_everything.names
    for world in (fed_everything, fed_valid_only):
        # 10,000 samples in a moment is a flood, which the input budget would cut
        # (world/input_budget.py, tested on its own): opened wide here to fuzz what follows it.
        world.budgets["telemetry"] = InputBudget(names, world.period_ns, burst=2 * INPUTS)
    robot = make_robot("robot2")
    robot.control_tick(robot.process.period_ns)
    template = robot.process.telemetry(robot.process.period_ns).model_dump(mode="json")
    rng = random.Random(20261203)
    target = "telemetry -> world"
    non_finite_or_huge_stamps = 0

    def valid(i: int, name: str) -> dict[str, Any]:
        message = copy.deepcopy(template)
        message["robot"] = name
        message["t_s"] = i * 0.05
        message["role"] = rng.choice(("leader", "follower"))
        message["term"] = rng.randrange(0, 5)
        return message

    for i in range(INPUTS):
        key_robot = rng.choice(names) if rng.random() < 0.95 else "robot9"
        roll = rng.random()
        if roll < 0.05:
            payload = random_bytes(rng, 200)
        elif roll < 0.1:
            payload = json_bytes(random_json(rng))
        elif roll < 0.2:  # a robot speaking for another
            payload = json_bytes(valid(i, rng.choice([n for n in names if n != key_robot])))
        elif roll < 0.3:  # a stamp no run reaches, or none at all
            message = valid(i, key_robot)
            message["t_s"] = rng.choice((float("nan"), float("inf"), -float("inf"), 1e300))
            payload = json_bytes(message)
            non_finite_or_huge_stamps += 1
        elif roll < 0.8:
            payload = json_bytes(mutate_json(rng, valid(i, key_robot)))
        else:
            payload = json_bytes(valid(i, key_robot))
        parsed = parse_message(TelemetryMessage, payload)
        accepted = parsed is not None and parsed.robot == key_robot and key_robot in names
        sample = _Sample(KEYS.telemetry(key_robot), _Payload(payload))
        refused_before = fed_everything.malformed_telemetry
        fed_everything._on_telemetry(sample)  # type: ignore[arg-type]
        fed_everything._take_telemetry()
        assert fed_everything.malformed_telemetry == refused_before + (not accepted), payload
        if accepted:
            fed_valid_only._on_telemetry(sample)  # type: ignore[arg-type]
            fed_valid_only._take_telemetry()
        LEDGER.record(target, ACCEPTED if accepted else "refused")
        if i % BATCH == BATCH - 1:
            assert _bookkeeping(fed_everything) == _bookkeeping(fed_valid_only)
    summary = fed_everything.summary()
    assert summary["malformed_telemetry"] == LEDGER.rejected(target)
    assert non_finite_or_huge_stamps > INPUTS // 20
    assert LEDGER.rejected(target) > INPUTS // 5
    assert LEDGER.outcomes[target][ACCEPTED] > INPUTS // 5
    assert fed_everything.reported_roles  # the valid samples were applied

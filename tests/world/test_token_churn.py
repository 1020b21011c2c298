"""A robot identity that declares and drops its liveliness token over and over (its own key,
which the router lets it hold): the world's main loop takes each robot's last change of a pass
only, so a churn makes no flood of `robot_up` / `robot_down` events (each one fsynced into
events.jsonl) and still ends with the token's true state.  On a real world process built
without a network (tests/fuzz/processes.py)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from tests.fuzz.processes import make_world

KEYS = SwarmKeys("lab")
CHURN = 10_000


@dataclass(frozen=True)
class _TokenSample:
    """What `_on_alive` reads of a zenoh.Sample: its key and whether the token came or went."""

    key_expr: str
    kind: zenoh.SampleKind


def _token(name: str, alive: bool) -> _TokenSample:
    kind = zenoh.SampleKind.PUT if alive else zenoh.SampleKind.DELETE
    return _TokenSample(KEYS.alive("robot", name), kind)


@pytest.mark.parametrize("ends_alive", [True, False], ids=["ends-up", "ends-down"])
def test_a_token_churned_between_two_passes_makes_one_change_at_most(ends_alive: bool) -> None:
    world = make_world()
    for name in world.names:
        world._on_alive(_token(name, True))  # type: ignore[arg-type]
    world._drain()
    world._time_started = True
    assert world.live == frozenset(world.names)
    events_before = len(world.event_log.events)
    for i in range(CHURN):  # robot2's token goes and comes back CHURN / 2 times
        world._on_alive(_token("robot2", i % 2 == 1))  # type: ignore[arg-type]
    if not ends_alive:
        world._on_alive(_token("robot2", False))  # type: ignore[arg-type]
    world._drain()
    recorded = [(e.kind, e.subject) for e in world.event_log.events[events_before:]]
    if ends_alive:
        assert recorded == []  # gone and back within one pass: no restart, nothing recorded
        assert "robot2" in world.live
    else:
        assert recorded == [("robot_down", "robot2")]
        assert "robot2" not in world.live
    assert {"robot1", "robot3"} <= world.live

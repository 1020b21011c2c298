"""When an act message wakes the world's main loop (world/runtime.py `_on_act`), and that a
late-drained act still changes the duty at its arrival instant (`_drain`), without a network.

In real time the loop is not woken per act: it drains the acts at its next wake-up and catches
the physics up to each act's arrival before it applies it, so nothing but the loop's work
changes; only a starvation hold, which an act may end, wakes it.  In lockstep an act wakes the
loop as soon as the tick's answers are all in (`_await_answers` sets the count).
tests/integration/test_starvation.py runs the real-time loop with real robots beside busy
processes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.wire import ActMessage, encode_act
from swarm_config.scenario import load_scenario
from world.runtime import WorldConfig, WorldProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


class ActSample:
    """What `_on_act` reads of a zenoh sample."""

    def __init__(self, robot: str, duty: float, tick: int = 0) -> None:
        self.key_expr = SwarmKeys("lab").act(robot)
        self.payload = self
        self._bytes = encode_act(
            ActMessage(tick=tick, duty=(duty,) * 4, enabled=(True,) * 4, watchdog_expired=False)
        )

    def to_bytes(self) -> bytes:
        return self._bytes


def world_of(lockstep: bool) -> WorldProcess:
    return WorldProcess(WorldConfig(scenario=PAPER, lockstep=lockstep), load_scenario(PAPER))


def test_a_real_time_act_wakes_the_loop_only_while_the_guard_holds_the_time() -> None:
    world = world_of(lockstep=False)
    for _ in range(5):
        world._on_act(ActSample("robot1", 0.5))  # type: ignore[arg-type]
    assert not world._wake.is_set()
    world.guard.holding = True  # waiting for a starved robot: its answer must end the hold
    world._on_act(ActSample("robot2", 0.5))  # type: ignore[arg-type]
    assert world._wake.is_set()
    assert world._acts.qsize() == 6


def test_a_lockstep_act_wakes_the_loop_outside_a_ticks_wait() -> None:
    world = world_of(lockstep=True)
    world._on_act(ActSample("robot1", 0.5))  # type: ignore[arg-type]
    assert world._wake.is_set()


def test_a_late_drained_act_is_applied_after_the_physics_caught_up_to_its_arrival() -> None:
    world = world_of(lockstep=False)
    seen: list[tuple[int, tuple[float, ...]]] = []

    def catch_up(arrival_mono_ns: int) -> None:  # what `_run_realtime` installs
        seen.append((arrival_mono_ns, tuple(world.duty[:, 0])))

    world._catch_up = catch_up
    for robot, duty in (("robot1", 0.25), ("robot3", 0.75), ("robot1", 0.5)):
        world._on_act(ActSample(robot, duty))  # type: ignore[arg-type]
    world._drain()
    # One catch-up per act, in arrival order, each with the duties as they were before it.
    assert [duties for _, duties in seen] == [(0, 0, 0), (0.25, 0, 0), (0.25, 0, 0.75)]
    stamps = [stamp for stamp, _ in seen]
    assert stamps == sorted(stamps)
    np.testing.assert_array_equal(world.duty[:, 0], [0.5, 0.0, 0.75])

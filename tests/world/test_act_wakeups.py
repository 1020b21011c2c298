"""When an act message wakes the world's main loop (world/runtime.py `_on_act`), and that a
late-drained act still changes the duty at its arrival instant, on the act grid (`_drain`,
`act_effect_ns`), without a network.

In real time the loop is not woken per act: it drains the acts at its next wake-up and catches
the physics up to each act's arrival before it applies it, so nothing but the loop's work
changes; only a starvation hold, which an act may end, wakes it.  In lockstep an act wakes the
loop as soon as the tick's answers are all in (`_await_answers` sets the count).
tests/integration/test_starvation.py runs the real-time loop with real robots beside busy
processes.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.wire import ActMessage, encode_act
from swarm_config.scenario import load_scenario
from world.runtime import WorldConfig, WorldProcess, act_effect_ns

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


def world_of(lockstep: bool, **settings: object) -> WorldProcess:
    config = WorldConfig(scenario=PAPER, lockstep=lockstep, **settings)  # type: ignore[arg-type]
    return WorldProcess(config, load_scenario(PAPER))


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

    def catch_up(arrival_ns: int, limit_ns: int) -> None:  # what `_run_realtime` installs
        seen.append((arrival_ns, tuple(world.duty[:, 0])))

    world._catch_up = catch_up
    for robot, duty in (("robot1", 0.25), ("robot3", 0.75), ("robot1", 0.5)):
        world._on_act(ActSample(robot, duty))  # type: ignore[arg-type]
    world._drain()
    # One catch-up per act, in arrival order, each with the duties as they were before it.
    assert [duties for _, duties in seen] == [(0, 0, 0), (0.25, 0, 0), (0.25, 0, 0.75)]
    stamps = [stamp for stamp, _ in seen]
    assert stamps == sorted(stamps)
    np.testing.assert_array_equal(world.duty[:, 0], [0.5, 0.0, 0.75])


def test_a_drain_takes_only_the_acts_queued_when_it_began() -> None:
    """Acts that keep coming while a pass catches the physics up wait for the next pass, so a
    starved world whose acts come faster than it catches up still gets to its sense ticks."""
    world = world_of(lockstep=False)
    caught_up = 0

    def catch_up(arrival_ns: int, limit_ns: int) -> None:
        nonlocal caught_up
        caught_up += 1
        if caught_up <= 1000:  # every catch-up outlasts the next act's arrival
            world._on_act(ActSample("robot2", 0.25))  # type: ignore[arg-type]

    world._catch_up = catch_up
    for robot in ("robot1", "robot2", "robot3"):
        world._on_act(ActSample(robot, 0.5))  # type: ignore[arg-type]
    world._drain()
    assert caught_up == 3
    assert world._acts.qsize() == 3
    np.testing.assert_array_equal(world.duty[:, 0], [0.5, 0.5, 0.5])
    world._drain()  # the next pass takes those that came during the first
    assert caught_up == 6
    np.testing.assert_array_equal(world.duty[:, 0], [0.5, 0.25, 0.5])


MS = 1_000_000


def test_an_act_takes_effect_at_the_next_grid_step_but_never_after_the_clock() -> None:
    assert act_effect_ns(0, 5 * MS, MS) == 0
    assert act_effect_ns(200_000, 5 * MS, MS) == MS
    assert act_effect_ns(MS, 5 * MS, MS) == MS
    assert act_effect_ns(MS + 1, 5 * MS, MS) == 2 * MS
    # Drained before its grid step came (or the next sense tick is sooner): the limit.
    assert act_effect_ns(1_200_000, 1_500_000, MS) == 1_500_000
    assert act_effect_ns(1_200_000, 1_100_000, MS) == 1_200_000  # never before it came
    assert act_effect_ns(1_234_567, 5 * MS, 0) == 1_234_567  # no grid: the very instant


class CountingEngine:
    """Counts the world engine's physics steps and where they end."""

    def __init__(self, world: WorldProcess) -> None:
        self.ends_ns: list[int] = []
        engine = world.engine
        step = engine.advance

        def advance(duty: object, dt_ns: int) -> None:
            step(duty, dt_ns)  # type: ignore[arg-type]
            self.ends_ns.append(engine.t_ns)

        engine.advance = advance  # type: ignore[method-assign]


def _drain_acts_that_came_at(
    world: WorldProcess, offsets_ns: list[int], drained_at_ns: int = 5 * MS
) -> list[int]:
    """Acts that came at `offsets_ns` after simulated time 0, drained at `drained_at_ns`
    with the next sense tick due at 10 ms: the ends of the physics steps taken."""
    now = time.monotonic_ns()
    start = now - drained_at_ns
    world.guard.start(0, 0, 0, start)
    world.next_sense_ns = 10 * MS  # tick 0 went out; the paper's period is 10 ms
    world._catch_up = world._catch_up_with_act
    counting = CountingEngine(world)
    for i, offset in enumerate(offsets_ns):
        robot = ("robot1", "robot2", "robot3")[i % 3]
        # What `_on_act` queues: the sender, the message and its arrival instant.
        world._acts.put((robot, ActSample(robot, 0.1 * (i + 1)).to_bytes(), start + offset))
    world._drain()
    return counting.ends_ns


# The grid tests run the clock unguarded, as the plain wall clock: a drain slower than the
# guard's lead (a first physics step compiled on the spot, a loaded host) would otherwise find
# the world behind its own clock and held (test_a_world_drained_seconds_late_... below).


def test_acts_that_come_within_one_grid_step_share_one_physics_step() -> None:
    world = world_of(lockstep=False, starvation_guard=False)  # act_grid_ms 1 by default
    ends = _drain_acts_that_came_at(world, [200_000, 500_000, 900_000, 2_300_000])
    assert ends == [MS, 3 * MS]
    np.testing.assert_allclose(world.duty[:, 0], [0.4, 0.2, 0.3])


def test_a_grid_step_that_does_not_divide_the_period_stops_at_the_sense_tick() -> None:
    world = world_of(lockstep=False, act_grid_ms=3.0, starvation_guard=False)
    # Drained late, at 11 ms: the second act's grid step (12 ms) is past the sense tick.
    ends = _drain_acts_that_came_at(world, [8_500_000, 9_500_000], drained_at_ns=11 * MS)
    assert ends == [9 * MS, 10 * MS]


def test_without_a_grid_each_act_has_its_own_physics_step() -> None:
    world = world_of(lockstep=False, act_grid_ms=0.0, starvation_guard=False)
    ends = _drain_acts_that_came_at(world, [200_000, 500_000, 900_000, 2_300_000])
    assert ends == [200_000, 500_000, 900_000, 2_300_000]


def test_a_world_drained_seconds_late_keeps_its_physics_within_the_lead_of_its_sense_ticks() -> (
    None
):
    """A starved world loop holds its own clock (world/realtime_guard.py, "The world's own
    lag"): acts that came seconds after its last sense tick reach its physics at most the
    lead beyond it, not seconds ahead of the sense ticks it still owes."""
    world = world_of(lockstep=False)
    lead_ns = world.config.starvation_lead_periods * 10 * MS
    ends = _drain_acts_that_came_at(
        world, [1_000 * MS, 2_000 * MS, 4_000 * MS], drained_at_ns=5_000 * MS
    )
    # No tick published yet: the world's own horizon is the lead past tick 0's due time.
    assert max(ends) == lead_ns
    np.testing.assert_allclose(world.duty[:, 0], [0.1, 0.2, 0.3])
    assert world.guard.holding
    stats = world.guard.stats()
    assert stats.world_behind_s == pytest.approx(5.0 - lead_ns / 1e9, abs=0.5)
    assert not any(stats.lapses.values())

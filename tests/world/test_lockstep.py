"""Lockstep pacing (`--max-speed`): ticks wait for their wall-clock time, never run early."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from world.engine import NS_PER_S
from world.runtime import LockstepPacer, WorldConfig

PERIOD_NS = 10_000_000


class FakeClock:
    """A wall clock that only moves when the pacer waits or the test says work took time."""

    def __init__(self) -> None:
        self.now_s = 100.0
        self.waits_s: list[float] = []

    def __call__(self) -> float:
        return self.now_s

    def wait(self, timeout_s: float) -> bool:
        self.waits_s.append(timeout_s)
        self.now_s += timeout_s
        return False


def test_ticks_start_no_faster_than_max_speed_times_the_wall_clock() -> None:
    clock = FakeClock()
    pacer = LockstepPacer(2.0, clock.wait, clock)
    tick_starts_s = []
    for tick in range(50):
        pacer.before_tick(tick * PERIOD_NS)
        tick_starts_s.append(clock.now_s)
        clock.now_s += 0.001  # a tick's work takes 1 ms, less than its 5 ms of wall time
    for tick, start_s in enumerate(tick_starts_s):
        assert start_s - tick_starts_s[0] == pytest.approx(tick * PERIOD_NS / NS_PER_S / 2.0)


def test_a_slow_tick_is_not_made_up_for_by_running_faster_than_max_speed_later() -> None:
    clock = FakeClock()
    pacer = LockstepPacer(1.0, clock.wait, clock)
    pacer.before_tick(0)
    clock.now_s += 0.5  # one tick took half a second: the run is behind its pace
    pacer.before_tick(PERIOD_NS)
    assert clock.waits_s == []  # late already: starts at once
    start_s = clock.now_s
    pacer.before_tick(2 * PERIOD_NS)  # and the next one a whole period later, not at once
    assert clock.waits_s == [pytest.approx(PERIOD_NS / NS_PER_S)]
    assert clock.now_s - start_s == pytest.approx(PERIOD_NS / NS_PER_S)


def test_without_max_speed_nothing_waits() -> None:
    clock = FakeClock()
    pacer = LockstepPacer(None, clock.wait, clock)
    for tick in range(10):
        pacer.before_tick(tick * PERIOD_NS)
    assert clock.waits_s == []


def test_max_speed_is_refused_for_a_real_time_world() -> None:
    with pytest.raises(ValidationError, match="max_speed"):
        WorldConfig(scenario="configs/scenarios/paper.yaml", max_speed=2.0)
    with pytest.raises(ValidationError, match="max_speed"):
        WorldConfig(scenario="configs/scenarios/paper.yaml", lockstep=True, max_speed=0.0)
    paced = WorldConfig(scenario="configs/scenarios/paper.yaml", lockstep=True, max_speed=0.5)
    assert paced.max_speed == 0.5

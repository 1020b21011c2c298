"""The lockstep barrier (every transition of world/lockstep.py's table) and pacing
(`--max-speed`: ticks wait for their wall-clock time, never run early)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from world.engine import NS_PER_S
from world.lockstep import TICK_PHASES, LockstepBarrier, LockstepPacer, LockstepProfile
from world.runtime import WorldConfig

PERIOD_NS = 10_000_000
ROBOTS = ("robot1", "robot2", "robot3")


def started_barrier() -> LockstepBarrier:
    """Three robots that joined before time started."""
    barrier = LockstepBarrier(ROBOTS)
    for name in ROBOTS:
        barrier.join(name)
    barrier.start()
    return barrier


def test_nobody_is_waited_for_before_anyone_joins() -> None:
    barrier = LockstepBarrier(ROBOTS)
    assert barrier.live() == frozenset() and barrier.waiting() == frozenset()
    assert barrier.complete()


def test_robots_that_joined_before_time_started_owe_tick_zero() -> None:
    barrier = LockstepBarrier(ROBOTS)
    barrier.join("robot1")
    assert barrier.waiting() == frozenset()  # joined: owes from the next tick only ...
    barrier.start()
    assert barrier.waiting() == {"robot1"}  # ... unless time starts now


def test_a_tick_completes_when_every_live_robot_has_acted() -> None:
    barrier = started_barrier()
    assert barrier.waiting() == set(ROBOTS)
    barrier.act("robot1", 0, 0)
    barrier.act("robot3", 0, 0)
    assert barrier.waiting() == {"robot2"}
    barrier.act("robot2", 0, 0)
    assert barrier.complete()
    barrier.advance()
    assert barrier.tick == 1 and barrier.waiting() == set(ROBOTS)


def test_an_act_for_an_older_tick_does_not_answer_this_one() -> None:
    barrier = started_barrier()
    for name in ROBOTS:
        barrier.act(name, 0, 0)
    barrier.advance()
    barrier.act("robot1", 0, 0)  # a late duplicate of tick 0
    assert "robot1" in barrier.waiting()
    barrier.act("robot1", 1, 0)
    assert "robot1" not in barrier.waiting()


def test_announced_frames_are_waited_for_after_the_act() -> None:
    barrier = started_barrier()
    barrier.act("robot1", 0, 2)
    barrier.act("robot2", 0, 0)
    barrier.act("robot3", 0, 0)
    assert barrier.waiting() == {"robot1"}
    barrier.frame("robot1")
    assert barrier.waiting() == {"robot1"}
    barrier.frame("robot1")
    assert barrier.complete()
    assert barrier.seats["robot1"].frames_owed == 0


def test_a_frame_that_overtakes_its_act_is_counted_all_the_same() -> None:
    barrier = started_barrier()
    barrier.frame("robot1")  # the frame arrived before the act that announces it
    assert barrier.seats["robot1"].frames_owed == -1
    barrier.act("robot1", 0, 1)
    assert "robot1" not in barrier.waiting()


def test_a_robot_that_leaves_is_not_waited_for() -> None:
    barrier = started_barrier()
    barrier.act("robot1", 0, 3)  # frames still owed when it dies
    barrier.leave("robot1")
    assert barrier.live() == {"robot2", "robot3"}
    assert barrier.waiting() == {"robot2", "robot3"}
    barrier.act("robot2", 0, 0)
    barrier.act("robot3", 0, 0)
    assert barrier.complete()


def test_a_robot_that_rejoins_is_waited_for_from_the_next_tick_with_a_clean_slate() -> None:
    barrier = started_barrier()
    barrier.act("robot2", 0, 5)
    barrier.leave("robot2")
    barrier.join("robot2")  # back during tick 0: its sense message may have been missed
    assert barrier.seats["robot2"].frames_owed == 0
    assert "robot2" not in barrier.waiting()
    barrier.act("robot1", 0, 0)
    barrier.act("robot3", 0, 0)
    assert barrier.complete()
    barrier.advance()
    assert "robot2" in barrier.waiting()  # tick 1: owed again
    barrier.act("robot2", 1, 0)
    assert "robot2" not in barrier.waiting()


def test_a_dead_robot_never_blocks_even_if_its_acts_still_arrive() -> None:
    barrier = started_barrier()
    barrier.leave("robot3")
    barrier.act("robot3", 0, 4)  # a late act from before the power cut
    assert "robot3" not in barrier.waiting()


def test_an_excused_robot_stays_live_and_is_waited_for_again_from_the_next_tick() -> None:
    barrier = started_barrier()
    barrier.act("robot1", 0, 0)
    barrier.act("robot2", 0, 1)  # answered, but its frame never comes
    assert barrier.waiting() == {"robot2", "robot3"}  # robot3's act never comes
    barrier.excuse("robot2")
    barrier.excuse("robot3")
    assert barrier.complete()
    assert barrier.live() == set(ROBOTS)
    assert barrier.seats["robot2"].frames_owed == 0
    barrier.advance()
    assert barrier.waiting() == set(ROBOTS)  # tick 1 is owed by all again
    for name in ROBOTS:
        barrier.act(name, 1, 0)
    assert barrier.complete()


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


def test_owed_counts_missing_acts_then_frames_still_to_come() -> None:
    """What the world's callbacks count down to before they wake its loop."""
    barrier = started_barrier()
    assert barrier.owed() == (3, 0)
    barrier.act("robot1", 0, 1)  # answered, one frame announced
    barrier.act("robot2", 0, 0)
    assert barrier.owed() == (1, 1)
    barrier.frame("robot3")  # robot3's frame came before its act
    barrier.act("robot3", 0, 1)
    assert barrier.owed() == (0, 1)
    barrier.frame("robot1")
    assert barrier.owed() == (0, 0) and barrier.complete()
    barrier.leave("robot2")
    barrier.advance()
    assert barrier.owed() == (2, 0)  # a robot that left is not waited for


def test_profile_sums_each_phase_and_keeps_recent_answers() -> None:
    profile = LockstepProfile()
    for start in (0, 1_000_000):
        # each phase takes 0.1 ms more than the one before it
        ends = [start]
        for k in range(len(TICK_PHASES)):
            ends.append(ends[-1] + (k + 1) * 100_000)
        profile.tick_done(ends)
    per_tick = profile.phase_ms_per_tick()
    assert list(per_tick) == list(TICK_PHASES)
    assert per_tick == {p: pytest.approx(0.1 * (k + 1)) for k, p in enumerate(TICK_PHASES)}
    assert profile.ticks == 2
    for took_ms in (3, 1, 2):
        profile.answered("robot1", took_ms * 1_000_000)
    assert profile.answer_p50_ms() == {"robot1": 2.0}
    for _ in range(3 * LockstepProfile.ANSWERS_KEPT):
        profile.answered("robot2", 5_000_000)
    assert len(profile.answer_ns["robot2"]) <= 2 * LockstepProfile.ANSWERS_KEPT
    with pytest.raises(ValueError, match="instants"):
        profile.tick_done([0, 1])

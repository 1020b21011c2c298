"""The robot's tick scheduler (robot_firmware/tick_scheduler.py): when a control tick runs, at
what simulation time, and how deadline misses are counted; on a fake monotonic clock."""

from __future__ import annotations

import pytest

from robot_firmware.tick_scheduler import RESYNC_PERIODS, RunTick, TickScheduler, Wait

PERIOD_NS = 10_000_000
MS = 1_000_000


def real_time(scheduler: TickScheduler, t_ns: int, arrival_ns: int) -> None:
    scheduler.sensed(t_ns, tick=0, lockstep=False, radio_frames=0, arrival_mono_ns=arrival_ns)


def test_no_tick_runs_before_the_first_sense_message() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    assert scheduler.poll(5 * PERIOD_NS, frames_queued=0) == Wait(0.05)
    assert scheduler.sim_time_ns(5 * PERIOD_NS) is None


def test_real_time_ticks_run_every_period_at_the_extrapolated_simulation_time() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, t_ns=2_000 * MS, arrival_ns=100 * MS)  # world at 2 s; our clock at 0.1
    first = scheduler.poll(100 * MS, 0)
    assert first == RunTick(sim_time_ns=2_000 * MS, tick=0, started_mono_ns=100 * MS)
    scheduler.finished(first, end_mono_ns=101 * MS)
    early = scheduler.poll(104 * MS, 0)
    assert isinstance(early, Wait) and early.timeout_s == pytest.approx(0.006)
    second = scheduler.poll(110 * MS + 300_000, 0)
    assert isinstance(second, RunTick)
    assert second.sim_time_ns == 2_010 * MS + 300_000  # 10.3 ms after the message arrived
    scheduler.finished(second, end_mono_ns=111 * MS)
    assert scheduler.timing.ticks == 1 and scheduler.timing.deadline_misses == 0
    assert list(scheduler.timing.jitter_ns) == [300_000]


def test_a_newer_sense_message_moves_the_simulation_clock() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, t_ns=0, arrival_ns=0)
    real_time(scheduler, t_ns=5_000 * MS, arrival_ns=3 * MS)  # the world jumped ahead
    assert scheduler.sim_time_ns(4 * MS) == 5_001 * MS


def run_ticks(scheduler: TickScheduler, starts_and_ends_ms: list[tuple[float, float]]) -> None:
    for start_ms, end_ms in starts_and_ends_ms:
        tick = scheduler.poll(round(start_ms * MS), 0)
        assert isinstance(tick, RunTick), (start_ms, tick)
        scheduler.finished(tick, round(end_ms * MS))


def test_a_tick_that_ends_after_its_period_is_a_deadline_miss() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, 0, 0)
    # deadlines at 0, 10, 20, 30 ms; the tick of 10 ms ends at 25 ms, after 10 + 10.
    run_ticks(scheduler, [(0, 1), (10, 25), (25, 26), (30, 31)])
    assert scheduler.timing.ticks == 3
    assert scheduler.timing.deadline_misses == 1
    assert list(scheduler.timing.recent_miss_ticks) == [1]


def test_a_tick_that_starts_more_than_a_period_late_is_a_deadline_miss() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, 0, 0)
    run_ticks(scheduler, [(0, 1), (10, 11), (31, 32)])  # the 20 ms deadline started at 31 ms
    assert scheduler.timing.deadline_misses == 1


def test_a_loop_far_behind_starts_its_deadlines_afresh_instead_of_bursting() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, 0, 0)
    run_ticks(scheduler, [(0, 1)])
    stalled_end_ms = 10 + (RESYNC_PERIODS + 2) * 10  # a stall of several periods
    run_ticks(scheduler, [(10, stalled_end_ms)])
    next_poll = scheduler.poll(stalled_end_ms * MS + 1, 0)
    assert isinstance(next_poll, Wait)  # not a burst of overdue ticks ...
    assert next_poll.timeout_s == pytest.approx(PERIOD_NS / 1e9, abs=1e-6)  # ... one period on


def lockstep(scheduler: TickScheduler, tick: int, frames: int, arrival_ns: int = 0) -> None:
    scheduler.sensed(
        tick * PERIOD_NS, tick=tick, lockstep=True, radio_frames=frames, arrival_mono_ns=arrival_ns
    )


def test_lockstep_runs_one_tick_per_sense_message_at_its_time() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    lockstep(scheduler, tick=7, frames=0)
    tick = scheduler.poll(123 * MS, 0)
    assert tick == RunTick(sim_time_ns=7 * PERIOD_NS, tick=7, started_mono_ns=123 * MS)
    scheduler.finished(tick, 124 * MS)
    assert scheduler.poll(500 * MS, 0) == Wait(0.05)  # no new message: no tick, however late
    assert scheduler.timing.ticks == 0  # lockstep has no deadlines


def test_lockstep_waits_for_the_frames_its_sense_message_announces() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    lockstep(scheduler, tick=3, frames=2)
    assert isinstance(scheduler.poll(0, frames_queued=1), Wait)
    assert scheduler.poll(0, frames_queued=2) == RunTick(3 * PERIOD_NS, 3, 0)


def test_after_a_rejoin_only_the_newest_queued_lockstep_tick_is_answered() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    lockstep(scheduler, tick=40, frames=0)
    lockstep(scheduler, tick=41, frames=0)
    first = scheduler.poll(0, 0)
    assert isinstance(first, RunTick) and first.tick == 41
    assert isinstance(scheduler.poll(0, 0), Wait)


def test_a_real_time_message_after_lockstep_switches_the_mode() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    lockstep(scheduler, tick=1, frames=0)
    real_time(scheduler, t_ns=50 * MS, arrival_ns=10 * MS)
    tick = scheduler.poll(10 * MS, 0)
    assert isinstance(tick, RunTick) and tick.tick == 0 and tick.sim_time_ns == 50 * MS

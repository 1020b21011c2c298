"""The robot's tick scheduler (robot_firmware/tick_scheduler.py): when a control tick runs, at
what simulation time, and how deadline misses are counted; on a fake monotonic clock."""

from __future__ import annotations

import itertools

import pytest

from robot_firmware.tick_scheduler import (
    SENSE_TIMEOUT_PERIODS,
    LoopStallWatch,
    RunTick,
    SafeStop,
    TickScheduler,
    Wait,
)

PERIOD_NS = 10_000_000
MS = 1_000_000


def real_time(scheduler: TickScheduler, t_ns: int, arrival_ns: int, tick: int = 0) -> None:
    scheduler.sensed(t_ns, tick=tick, lockstep=False, radio_frames=0, arrival_mono_ns=arrival_ns)


class RealTimeWorld:
    """A real-time world's sense messages: one every `every_ms` of wall time, each
    `advance_ms` of simulation time later than the one before (advance < every: the world
    runs slower than the wall clock), from simulation time `t0_ms` at wall time 0."""

    def __init__(
        self,
        scheduler: TickScheduler,
        t0_ms: float = 0.0,
        every_ms: float = 10.0,
        advance_ms: float = 10.0,
    ) -> None:
        self.scheduler = scheduler
        self.t0_ms, self.every_ms, self.advance_ms = t0_ms, every_ms, advance_ms
        self.sent = 0

    def run_until(self, wall_ms: float) -> None:
        """Deliver every message due by `wall_ms`."""
        while self.sent * self.every_ms <= wall_ms:
            k = self.sent
            real_time(
                self.scheduler,
                t_ns=round((self.t0_ms + k * self.advance_ms) * MS),
                arrival_ns=round(k * self.every_ms * MS),
                tick=k,
            )
            self.sent += 1


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
    early = scheduler.poll(109 * MS, 0)
    assert isinstance(early, Wait)  # for the world's next message
    real_time(scheduler, t_ns=2_010 * MS, arrival_ns=110 * MS, tick=1)
    second = scheduler.poll(110 * MS + 300_000, 0)
    assert isinstance(second, RunTick)
    assert second.sim_time_ns == 2_010 * MS + 300_000  # 0.3 ms after the message arrived
    scheduler.finished(second, end_mono_ns=111 * MS)
    assert scheduler.timing.ticks == 1 and scheduler.timing.deadline_misses == 0
    assert list(scheduler.timing.jitter_ns) == [300_000]


def test_a_real_time_tick_answers_the_newest_sense_messages_tick() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    for k in range(3):  # three messages queued while the loop was busy
        real_time(scheduler, t_ns=k * PERIOD_NS, arrival_ns=k * PERIOD_NS, tick=40 + k)
    tick = scheduler.poll(2 * PERIOD_NS, 0)
    assert isinstance(tick, RunTick) and tick.tick == 42


def test_a_newer_sense_message_moves_the_simulation_clock() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, t_ns=0, arrival_ns=0)
    real_time(scheduler, t_ns=5_000 * MS, arrival_ns=3 * MS)  # the world jumped ahead
    assert scheduler.sim_time_ns(4 * MS) == 5_001 * MS


def test_the_loop_never_runs_ahead_of_the_worlds_newest_message() -> None:
    """The world holds its time (no new message): the loop runs no tick past it, and its
    clock stops at most a period past it."""
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, t_ns=500 * MS, arrival_ns=0)
    ticks = []
    for now_ms in range(0, 90):
        decision = scheduler.poll(now_ms * MS, 0)
        assert not isinstance(decision, SafeStop)
        if isinstance(decision, RunTick):
            ticks.append(decision.sim_time_ns)
            scheduler.finished(decision, now_ms * MS)
    assert ticks == [500 * MS]
    assert scheduler.sim_time_ns(4 * MS) == 504 * MS
    assert scheduler.sim_time_ns(80 * MS) == 510 * MS


@pytest.mark.parametrize("rate", [1.0, 0.5, 0.2])
def test_a_slowed_world_gets_one_tick_per_period_of_its_time(rate: float) -> None:
    """A world at real-time factor `rate`: ticks stay one period of simulation time apart
    (the control law's fixed step), the world's slowness is no deadline miss, and no tick
    runs at a time the world has not reached within a period."""
    scheduler = TickScheduler(PERIOD_NS)
    world = RealTimeWorld(scheduler, t0_ms=1_000.0, every_ms=10.0 / rate)
    ticks: list[RunTick] = []
    for now_us in range(0, 2_000_000, 250):
        now_ms = now_us / 1_000
        world.run_until(now_ms)
        decision = scheduler.poll(now_us * 1_000, 0)
        assert not isinstance(decision, SafeStop)
        if isinstance(decision, RunTick):
            newest_ms = world.t0_ms + (world.sent - 1) * world.advance_ms
            assert decision.sim_time_ns <= (newest_ms + 10.0) * MS
            ticks.append(decision)
            scheduler.finished(decision, now_us * 1_000 + 500_000)
    gaps_ms = {(b.sim_time_ns - a.sim_time_ns) / MS for a, b in itertools.pairwise(ticks)}
    assert gaps_ms == {10.0}, gaps_ms
    assert len(ticks) == pytest.approx(2_000 * rate / 10, abs=1)
    assert scheduler.timing.deadline_misses == 0


def test_a_repeated_sense_message_keeps_the_loop_waiting_instead_of_stopping() -> None:
    """The world holds its time for 300 ms and repeats its newest message every period:
    the loop neither ticks nor stops safely, and carries on when the world does."""
    scheduler = TickScheduler(PERIOD_NS)
    real_time(scheduler, t_ns=700 * MS, arrival_ns=0, tick=70)
    decisions = []
    for now_ms in range(0, 300):
        if now_ms % 10 == 0 and now_ms > 0:
            real_time(scheduler, t_ns=700 * MS, arrival_ns=now_ms * MS, tick=70)  # a repeat
        decision = scheduler.poll(now_ms * MS, 0)
        if isinstance(decision, RunTick | SafeStop):
            decisions.append(decision)
            scheduler.finished(decision, now_ms * MS)
    assert [d.sim_time_ns for d in decisions] == [700 * MS]
    assert all(isinstance(d, RunTick) for d in decisions) and not scheduler.safe_stopped
    real_time(scheduler, t_ns=710 * MS, arrival_ns=300 * MS, tick=71)  # the world moves on
    tick = scheduler.poll(300 * MS, 0)
    assert tick == RunTick(710 * MS, 71, 300 * MS)  # not `resumed`: the world was there
    scheduler.finished(tick, 301 * MS)
    assert scheduler.timing.deadline_misses == 0


def run_ticks(
    scheduler: TickScheduler, starts_and_ends_ms: list[tuple[float, float]], world: RealTimeWorld
) -> None:
    for start_ms, end_ms in starts_and_ends_ms:
        world.run_until(start_ms)
        tick = scheduler.poll(round(start_ms * MS), 0)
        assert isinstance(tick, RunTick), (start_ms, tick)
        scheduler.finished(tick, round(end_ms * MS))


def test_a_tick_that_ends_after_its_period_is_a_deadline_miss() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    world = RealTimeWorld(scheduler)
    # deadlines at 0, 10, 20, 30 ms; the tick of 10 ms ends at 25 ms, after 10 + 10: the 20 ms
    # deadline passed while it ran and is skipped.
    run_ticks(scheduler, [(0, 1), (10, 25), (30, 31)], world)
    world.run_until(35)
    assert isinstance(scheduler.poll(35 * MS, 0), Wait)
    assert scheduler.timing.ticks == 2
    assert scheduler.timing.deadline_misses == 1
    assert list(scheduler.timing.recent_miss_ticks) == [1]


def test_a_tick_that_starts_more_than_a_period_late_is_a_deadline_miss() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    world = RealTimeWorld(scheduler)
    run_ticks(scheduler, [(0, 1), (10, 11), (31, 32)], world)  # the 20 ms deadline started at 31
    assert scheduler.timing.deadline_misses == 1


def test_a_loop_far_behind_answers_the_newest_message_once_instead_of_bursting() -> None:
    """A tick that took seven periods: the deadlines that passed meanwhile are skipped, but the
    newest message is answered at once (the world may hold its time for that answer)."""
    scheduler = TickScheduler(PERIOD_NS)
    world = RealTimeWorld(scheduler)
    run_ticks(scheduler, [(0, 1)], world)
    stalled_end_ms = 10 + 7 * 10
    run_ticks(scheduler, [(10, stalled_end_ms)], world)
    world.run_until(stalled_end_ms)  # the messages that queued up meanwhile
    caught_up = scheduler.poll(stalled_end_ms * MS + 1, 0)
    assert caught_up == RunTick(stalled_end_ms * MS + 1, 8, stalled_end_ms * MS + 1)
    scheduler.finished(caught_up, (stalled_end_ms + 1) * MS)
    assert isinstance(scheduler.poll((stalled_end_ms + 2) * MS, 0), Wait)  # no burst ...
    world.run_until(stalled_end_ms + 10)
    following = scheduler.poll((stalled_end_ms + 10) * MS, 0)  # ... the next grid point
    assert isinstance(following, RunTick) and following.sim_time_ns == (stalled_end_ms + 10) * MS
    assert scheduler.timing.deadline_misses == 1


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


def test_only_a_lockstep_tick_short_of_its_announced_frames_awaits_frames() -> None:
    """What decides whether the robot's loop looks for frames again shortly instead of
    sleeping until its next input (robot_firmware/runtime.py, `FRAME_POLL_S`)."""
    scheduler = TickScheduler(PERIOD_NS)
    assert not scheduler.awaits_frames  # no sense message yet: it will wake the loop itself
    real_time(scheduler, 0, 0)
    assert not scheduler.awaits_frames  # real time: the next tick takes what has come
    lockstep(scheduler, tick=3, frames=0)
    assert not scheduler.awaits_frames
    assert isinstance(scheduler.poll(0, frames_queued=0), RunTick)
    lockstep(scheduler, tick=4, frames=2)
    assert scheduler.awaits_frames
    assert isinstance(scheduler.poll(0, frames_queued=1), Wait)
    assert scheduler.awaits_frames
    assert isinstance(scheduler.poll(0, frames_queued=2), RunTick)
    assert not scheduler.awaits_frames  # answered: the next frames are the next tick's


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


SENSE_TIMEOUT_NS = SENSE_TIMEOUT_PERIODS * PERIOD_NS


def run_until_safe_stop(scheduler: TickScheduler, sense_every_ms: int, last_sense_ms: int) -> int:
    """Real-time ticks every period with sense messages every `sense_every_ms` until
    `last_sense_ms`, then none (the loop waits); returns the monotonic time (ms) of the first
    `SafeStop`."""
    for now_ms in range(0, 10_000, 10):
        if now_ms <= last_sense_ms and now_ms % sense_every_ms == 0:
            real_time(scheduler, t_ns=(5_000 + now_ms) * MS, arrival_ns=now_ms * MS)
        decision = scheduler.poll(now_ms * MS, 0)
        if isinstance(decision, SafeStop):
            assert decision.entered
            return now_ms
        if now_ms > last_sense_ms:
            assert isinstance(decision, Wait), (now_ms, decision)
            continue
        assert isinstance(decision, RunTick), (now_ms, decision)
        assert not decision.resumed
        scheduler.finished(decision, now_ms * MS + MS)
    raise AssertionError("no safe stop")


def test_real_time_loop_stops_safely_when_sense_messages_stop() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    assert scheduler.sense_timeout_ns == 100 * MS
    stop_ms = run_until_safe_stop(scheduler, sense_every_ms=10, last_sense_ms=500)
    # the newest message is more than the time-out old at the first deadline after it
    assert 500 + 100 < stop_ms <= 500 + 100 + 10
    assert scheduler.safe_stopped and scheduler.safe_stops == 1


def test_a_safe_stop_repeats_every_period_until_sense_messages_come_back() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    stop_ms = run_until_safe_stop(scheduler, sense_every_ms=10, last_sense_ms=100)
    first = scheduler.poll(stop_ms * MS, 0)
    assert isinstance(first, SafeStop)
    scheduler.finished(first, stop_ms * MS + MS)
    early = scheduler.poll(stop_ms * MS + 5 * MS, 0)
    assert isinstance(early, Wait)
    again = scheduler.poll(stop_ms * MS + 11 * MS, 0)
    assert isinstance(again, SafeStop) and not again.entered
    assert again.sim_time_ns == (5_000 + 100 + stop_ms + 11 - 100) * MS  # time still runs
    assert scheduler.safe_stops == 1
    assert scheduler.timing.deadline_misses == 0  # safe-stop periods are not ticks


def test_after_a_safe_stop_the_first_tick_uses_the_new_message_and_is_marked_resumed() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    stop_ms = run_until_safe_stop(scheduler, sense_every_ms=10, last_sense_ms=100)
    stopped = scheduler.poll(stop_ms * MS, 0)
    assert isinstance(stopped, SafeStop)
    scheduler.finished(stopped, stop_ms * MS)
    back_ms = stop_ms + 3_000  # the world came back 3 s later, at simulation time 20 s
    real_time(scheduler, t_ns=20_000 * MS, arrival_ns=back_ms * MS)
    assert not scheduler.safe_stopped
    tick = scheduler.poll(back_ms * MS, 0)
    assert tick == RunTick(20_000 * MS, 0, back_ms * MS, resumed=True)
    scheduler.finished(tick, back_ms * MS + MS)
    real_time(scheduler, t_ns=20_010 * MS, arrival_ns=back_ms * MS + 10 * MS)
    following = scheduler.poll(back_ms * MS + 10 * MS, 0)
    assert isinstance(following, RunTick) and not following.resumed
    scheduler.finished(following, back_ms * MS + 11 * MS)
    assert scheduler.timing.ticks == tick_count_before_stop(100) + 1
    assert scheduler.timing.deadline_misses == 0  # the gap is not a burst of misses


def tick_count_before_stop(last_sense_ms: int) -> int:
    """Ticks recorded by `run_until_safe_stop` (the first one has no period)."""
    return last_sense_ms // 10


def test_a_frozen_loop_with_messages_waiting_resynchronises_without_a_burst() -> None:
    """SIGSTOP, then SIGCONT: the messages that were waiting arrive at once, long after the
    previous one; the loop does not run the ticks it missed, and marks the next one resumed."""
    scheduler = TickScheduler(PERIOD_NS)
    run_ticks(scheduler, [(0, 1), (10, 11)], RealTimeWorld(scheduler))
    thawed_ms = 5_000
    for t_ms in (15, 25, 35):  # queued before the freeze, applied on waking
        real_time(scheduler, t_ns=t_ms * MS, arrival_ns=thawed_ms * MS)
    tick = scheduler.poll(thawed_ms * MS, 0)
    assert tick == RunTick(35 * MS, 0, thawed_ms * MS, resumed=True)
    scheduler.finished(tick, thawed_ms * MS + MS)
    assert isinstance(scheduler.poll(thawed_ms * MS + 2 * MS, 0), Wait)  # no burst
    assert scheduler.timing.deadline_misses == 0


def test_lockstep_has_no_sense_time_out() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    lockstep(scheduler, tick=1, frames=0, arrival_ns=0)
    tick = scheduler.poll(0, 0)
    assert isinstance(tick, RunTick)
    scheduler.finished(tick, MS)
    assert scheduler.poll(60_000 * MS, 0) == Wait(0.05)  # a minute without the world
    lockstep(scheduler, tick=2, frames=0, arrival_ns=60_000 * MS)
    tick = scheduler.poll(60_000 * MS, 0)
    assert tick == RunTick(2 * PERIOD_NS, 2, 60_000 * MS, resumed=False)
    assert not scheduler.safe_stopped


@pytest.mark.parametrize("timeout_ns", [0, -1])
def test_a_sense_time_out_must_be_positive(timeout_ns: int) -> None:
    with pytest.raises(ValueError, match="positive"):
        TickScheduler(PERIOD_NS, sense_timeout_ns=timeout_ns)


def _sensed_epoch(
    scheduler: TickScheduler, t_ns: int, arrival_ns: int, epoch: int, lockstep: bool = False
) -> None:
    tick = t_ns // PERIOD_NS if lockstep else 0
    scheduler.sensed(t_ns, tick, lockstep, 0, arrival_ns, epoch)


def _run_ticks(
    scheduler: TickScheduler, start_ns: int, count: int, t0_ns: int, epoch: int
) -> list[RunTick]:
    """`count` ticks a period apart from wall time `start_ns`, a sense message of the world at
    `t0_ns` (at `start_ns`) and on before each."""
    ticks = []
    for k in range(count):
        _sensed_epoch(scheduler, t0_ns + k * PERIOD_NS, start_ns + k * PERIOD_NS, epoch)
        decision = scheduler.poll(start_ns + k * PERIOD_NS, 0)
        assert isinstance(decision, RunTick)
        scheduler.finished(decision, start_ns + k * PERIOD_NS + MS)
        ticks.append(decision)
    return ticks


@pytest.mark.parametrize("new_world_t_ns", [3_000 * MS, 9_000 * MS])
def test_a_new_world_epoch_moves_the_clock_backwards_or_forwards_at_once(
    new_world_t_ns: int,
) -> None:
    scheduler = TickScheduler(PERIOD_NS)
    before = _run_ticks(scheduler, 0, 3, t0_ns=5_000 * MS, epoch=11)
    assert not any(t.new_epoch or t.resumed for t in before)
    # The restarted world's first sense message, 35 ms later (no sense time-out).
    _sensed_epoch(scheduler, new_world_t_ns, 35 * MS, epoch=12)
    first = scheduler.poll(35 * MS, 0)
    assert first == RunTick(new_world_t_ns, 0, 35 * MS, resumed=True, new_epoch=True)
    scheduler.finished(first, 36 * MS)
    assert scheduler.epoch == 12 and scheduler.epoch_changes == 1
    later = _run_ticks(scheduler, 45 * MS, 3, t0_ns=new_world_t_ns + PERIOD_NS, epoch=12)
    assert [t.sim_time_ns for t in later] == [new_world_t_ns + k * PERIOD_NS for k in (1, 2, 3)]
    assert not any(t.new_epoch or t.resumed for t in later)


def test_sense_messages_of_the_same_epoch_are_no_jump() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    for k in range(5):
        _sensed_epoch(scheduler, k * PERIOD_NS, k * PERIOD_NS, epoch=7)
        decision = scheduler.poll(k * PERIOD_NS, 0)
        assert isinstance(decision, RunTick) and not decision.new_epoch
        scheduler.finished(decision, k * PERIOD_NS + MS)
    assert scheduler.epoch_changes == 0


def test_lockstep_answers_the_resumed_worlds_tick_after_a_new_epoch() -> None:
    scheduler = TickScheduler(PERIOD_NS)
    _sensed_epoch(scheduler, 5_000 * MS, 0, epoch=1, lockstep=True)
    assert scheduler.poll(0, 0) == RunTick(5_000 * MS, 500, 0)
    _sensed_epoch(scheduler, 4_200 * MS, 2 * MS, epoch=2, lockstep=True)
    resumed = scheduler.poll(3 * MS, 0)
    assert resumed == RunTick(4_200 * MS, 420, 3 * MS, resumed=True, new_epoch=True)
    _sensed_epoch(scheduler, 4_210 * MS, 4 * MS, epoch=2, lockstep=True)
    assert scheduler.poll(5 * MS, 0) == RunTick(4_210 * MS, 421, 5 * MS)


def test_a_loop_that_comes_round_late_is_a_stall_and_tokens_settle_after_it() -> None:
    watch = LoopStallWatch(stall_ns=500 * MS, settle_ns=2_000 * MS)
    assert watch.came_round(0) == 0 and not watch.settling(0)  # nothing due yet
    watch.due(10 * MS)
    assert watch.came_round(400 * MS) == 0  # late, but less than a stall (a busy host)
    watch.due(410 * MS)
    assert watch.came_round(3_410 * MS) == 3_000 * MS  # frozen for 3 s
    assert watch.stalls == 1
    assert watch.settling(3_410 * MS) and watch.settling(5_409 * MS)
    assert not watch.settling(5_410 * MS)
    watch.due(5_420 * MS)
    assert watch.came_round(5_420 * MS) == 0 and watch.stalls == 1

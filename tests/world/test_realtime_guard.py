"""The real-time starvation guard (world/realtime_guard.py): every row of its seat table, the
held clock that slows the run instead of racing to catch up, the hold limit for frozen robots,
and the windowed real-time factor; on a fake monotonic clock."""

from __future__ import annotations

import pytest

from world.realtime_guard import RealTimeFactorWindow, RealTimeGuard, SenseLateness

PERIOD_NS = 10_000_000
MS = 1_000_000
HOLD_LIMIT_NS = 500 * MS
ROBOTS = ("robot1", "robot2", "robot3")
LEAD = 1
"""The tests work the rule through with one period of lead (the world's default is
`realtime_guard.LEAD_PERIODS`); `test_the_lead_sets_the_horizon` takes others."""


def running_guard(enabled: bool = True, lead: int = LEAD) -> RealTimeGuard:
    """Three live robots that have answered tick 0; time starts at 0 with tick 0 due at 0."""
    guard = RealTimeGuard(ROBOTS, PERIOD_NS, HOLD_LIMIT_NS, lead_periods=lead, enabled=enabled)
    guard.start(tick=0, tick_time_ns=0, sim_ns=0, mono_ns=0)
    guard.published(0)
    for name in ROBOTS:
        guard.join(name)
        guard.answer(name, 0)
    assert guard.sim_time_ns(0) == 0
    return guard


def publish_through(guard: RealTimeGuard, tick: int) -> None:
    for k in range(tick + 1):
        guard.published(k)


def run_world(
    guard: RealTimeGuard, from_ms: int, to_ms: int, answering: tuple[str, ...]
) -> list[int]:
    """The world's loop, asking the time every millisecond of wall time: it publishes each
    tick whose time has come, and the `answering` robots answer it at once.  Returns the
    simulation time at each millisecond."""
    times = []
    tick = max(guard.seats[n].answered or 0 for n in answering)
    for mono_ms in range(from_ms, to_ms):
        now_ns = guard.sim_time_ns(mono_ms * MS)
        times.append(now_ns)
        while guard.tick_time_ns(tick + 1) <= now_ns:
            tick += 1
            guard.published(tick)
            for name in answering:
                guard.answer(name, tick)
    return times


def test_time_runs_with_the_wall_clock_while_every_robot_keeps_up() -> None:
    guard = running_guard()
    for k in range(1, 50):
        publish_through(guard, k)
        for name in ROBOTS:
            guard.answer(name, k)
        assert guard.sim_time_ns(k * PERIOD_NS + 3 * MS) == k * PERIOD_NS + 3 * MS
    assert not guard.holding and guard.stats().held_s == 0.0


@pytest.mark.parametrize("lead", [0, 2, 3])
def test_the_lead_sets_the_horizon(lead: int) -> None:
    guard = running_guard(lead=lead)
    publish_through(guard, 5)
    for name in ("robot1", "robot3"):
        guard.answer(name, 5)
    guard.answer("robot2", 3)
    # tick 3's period ends at 40 ms; `lead` periods beyond it
    assert guard.horizon_ns() == (40 + 10 * lead) * MS
    assert guard.sim_time_ns(200 * MS) == (40 + 10 * lead) * MS


def test_time_stops_one_period_past_the_slowest_robots_answered_period() -> None:
    guard = running_guard()
    publish_through(guard, 5)
    for name in ("robot1", "robot3"):
        guard.answer(name, 5)
    guard.answer("robot2", 3)  # starved: its newest answer is tick 3
    # tick 3's period ends at 40 ms; one period beyond it is 50 ms
    assert guard.horizon_ns() == 50 * MS
    assert guard.sim_time_ns(80 * MS) == 50 * MS
    assert guard.holding


def test_a_held_run_carries_on_from_where_it_stood_instead_of_catching_up() -> None:
    guard = running_guard()
    publish_through(guard, 3)
    for name in ROBOTS:
        guard.answer(name, 1 if name == "robot2" else 3)
    assert guard.sim_time_ns(30 * MS) == 30 * MS  # the horizon: tick 1 answered
    assert guard.sim_time_ns(75 * MS) == 30 * MS  # held for 45 ms of wall time
    guard.answer("robot2", 3)
    assert guard.sim_time_ns(75 * MS) == 30 * MS  # released: from where it was held ...
    assert guard.sim_time_ns(80 * MS) == 35 * MS  # ... at the wall clock's pace
    stats = guard.stats()
    assert stats.held_s == pytest.approx(0.045) and stats.holds == 1
    assert stats.held_for_s == {"robot1": 0.0, "robot2": pytest.approx(0.045), "robot3": 0.0}
    assert stats.longest_hold_s == pytest.approx(0.045)


def test_a_joined_robot_is_not_waited_for_before_its_first_answer() -> None:
    guard = running_guard()
    guard.leave("robot2")
    guard.join("robot2")  # a restarted robot, still booting
    assert "robot2" not in guard.waited_for() and "robot2" in guard.braked()
    publish_through(guard, 3)
    for name in ("robot1", "robot3"):
        guard.answer(name, 3)
    assert guard.sim_time_ns(30 * MS) == 30 * MS
    guard.answer("robot2", 3)
    assert guard.sim_time_ns(31 * MS) == 31 * MS
    assert "robot2" in guard.waited_for() and not guard.braked()


def test_a_robot_that_left_is_never_waited_for() -> None:
    guard = running_guard()
    guard.leave("robot2")  # killed: its token went
    publish_through(guard, 9)
    for name in ("robot1", "robot3"):
        guard.answer(name, 9)
    assert guard.sim_time_ns(95 * MS) == 95 * MS
    assert "robot2" not in guard.braked()  # the world brakes a dead body anyway


def test_an_answer_to_a_tick_not_yet_published_is_another_worlds() -> None:
    guard = running_guard()
    guard.answer("robot2", 900)  # from the world that ran before a restart
    assert guard.seats["robot2"].answered == 0


def test_answers_never_go_back() -> None:
    guard = running_guard()
    publish_through(guard, 4)
    guard.answer("robot2", 4)
    guard.answer("robot2", 0)  # a safe-stop period's act carries no tick
    assert guard.seats["robot2"].answered == 4


def test_a_frozen_robot_holds_the_world_no_longer_than_the_hold_limit() -> None:
    guard = running_guard()
    # robot2 froze after answering tick 0: the world stands at 20 ms until the limit
    times = run_world(guard, 0, 1_000, answering=("robot1", "robot3"))
    held_ms = sum(1 for t in times if t == 20 * MS)
    print(f"\nheld for a frozen robot: {held_ms} ms of wall time (limit 500 ms)")
    assert HOLD_LIMIT_NS / MS <= held_ms <= HOLD_LIMIT_NS / MS + 2
    assert "robot2" in guard.braked() and "robot2" not in guard.waited_for()
    assert guard.stats().lapses == {"robot1": 0, "robot2": 1, "robot3": 0}
    assert guard.stats().longest_hold_s == pytest.approx(HOLD_LIMIT_NS / 1e9, abs=0.003)
    # then the others carry the world on at the wall clock's pace
    assert times[-1] - times[-100] == 99 * MS


def test_a_lapsed_robot_is_waited_for_again_once_it_has_caught_up() -> None:
    guard = running_guard()
    times = run_world(guard, 0, 600, answering=("robot1", "robot3"))  # robot2 lapses
    assert "robot2" in guard.braked()
    guard.answer("robot2", 3)  # thawed, but behind: still not waited for
    run_world(guard, 600, 601, answering=("robot1", "robot3"))
    assert "robot2" in guard.braked()
    newest = guard.seats["robot1"].answered
    assert newest is not None
    guard.answer("robot2", newest)  # caught up
    after = run_world(guard, 601, 700, answering=("robot1", "robot2", "robot3"))
    assert "robot2" in guard.waited_for() and not guard.braked()
    assert after[-1] - after[0] == 98 * MS and after[0] >= times[-1]


def test_the_hold_timer_counts_only_while_the_robot_holds_the_world() -> None:
    """A robot that is a little late every period never lapses, however long the run."""
    guard = running_guard()
    mono_ns = 0
    for k in range(1, 300):  # 3 s of wall time: six hold limits
        publish_through(guard, k)
        guard.answer("robot1", k)
        guard.answer("robot3", k)
        guard.answer("robot2", k - 1)
        mono_ns += PERIOD_NS
        guard.sim_time_ns(mono_ns)
    assert guard.stats().lapses["robot2"] == 0 and not guard.braked()


def test_an_exempt_robot_is_not_waited_for_nor_braked() -> None:
    guard = running_guard()
    guard.exempt("robot2", True)  # under a tick_slow fault
    publish_through(guard, 9)
    for name in ("robot1", "robot3"):
        guard.answer(name, 9)
    assert guard.sim_time_ns(95 * MS) == 95 * MS
    assert not guard.braked()
    guard.exempt("robot2", False)  # cleared: waited for once it has caught up
    assert "robot2" not in guard.waited_for()
    guard.answer("robot2", 9)
    guard.sim_time_ns(96 * MS)
    assert "robot2" in guard.waited_for()


def test_a_world_behind_its_own_clock_holds_it_as_a_starved_robot_would() -> None:
    guard = running_guard()
    publish_through(guard, 5)
    for name in ROBOTS:
        guard.answer(name, 5)  # every robot has answered every tick published
    # The world's loop stalls: tick 6 is due at 60 ms and not published.  Its own seat's
    # horizon, one period beyond tick 5's period, is 70 ms.
    assert guard.horizon_ns() == 70 * MS
    assert guard.sim_time_ns(69 * MS) == 69 * MS and not guard.holding
    assert guard.sim_time_ns(2_000 * MS) == 70 * MS and guard.holding
    stats = guard.stats()
    assert stats.held_s == pytest.approx(1.930) and stats.world_behind_s == stats.held_s
    # No robot is to blame: none held the world, none lapsed past the hold limit (500 ms).
    assert stats.held_for_s == dict.fromkeys(ROBOTS, 0.0)
    assert stats.lapses == dict.fromkeys(ROBOTS, 0) and not guard.braked()
    # Caught up, the world carries on from where its clock stood instead of racing.
    guard.published(6)
    for name in ROBOTS:
        guard.answer(name, 6)
    assert guard.sim_time_ns(2_005 * MS) == 75 * MS and not guard.holding


def test_a_robot_behind_a_world_that_is_behind_is_blamed_only_for_its_own_lag() -> None:
    guard = running_guard()
    publish_through(guard, 5)
    for name in ("robot1", "robot3"):
        guard.answer(name, 5)
    guard.answer("robot2", 3)  # robot2's horizon, 50 ms, binds before the world's, 70 ms
    times = run_world_stalled(guard, 0, 1_000)
    assert times[-1] == 70 * MS  # robot2 lapsed; then the world's own lag held the time
    stats = guard.stats()
    assert stats.lapses == {"robot1": 0, "robot2": 1, "robot3": 0}
    assert stats.held_for_s["robot2"] == pytest.approx(HOLD_LIMIT_NS / 1e9, abs=0.002)
    assert stats.world_behind_s == pytest.approx(1.0 - 0.07 - HOLD_LIMIT_NS / 1e9, abs=0.003)


def run_world_stalled(guard: RealTimeGuard, from_ms: int, to_ms: int) -> list[int]:
    """A world loop that asks the time every millisecond and publishes nothing."""
    return [guard.sim_time_ns(mono_ms * MS) for mono_ms in range(from_ms, to_ms)]


def test_with_the_guard_off_the_clock_is_the_wall_clock() -> None:
    guard = running_guard(enabled=False)
    guard.answer("robot2", 0)
    # Neither the robots nor the world, which has published tick 0 only, hold it.
    assert guard.sim_time_ns(3_000 * MS) == 3_000 * MS
    assert guard.horizon_ns() is None and not guard.braked() and not guard.waited_for()
    assert guard.stats().held_s == 0.0


def test_a_resumed_world_maps_ticks_from_where_it_resumed() -> None:
    guard = RealTimeGuard(ROBOTS, PERIOD_NS, HOLD_LIMIT_NS, lead_periods=LEAD)
    guard.start(tick=4_200, tick_time_ns=42_000 * MS, sim_ns=41_995 * MS, mono_ns=7 * MS)
    assert guard.tick_time_ns(4_210) == 42_100 * MS
    guard.published(4_200)
    guard.join("robot1")
    guard.answer("robot1", 4_200)
    assert guard.sim_time_ns(7 * MS) == 41_995 * MS
    assert guard.horizon_ns() == 42_020 * MS
    assert guard.sim_time_ns(100 * MS) == 42_020 * MS


def test_an_earlier_instant_gets_no_later_time() -> None:
    guard = running_guard()
    publish_through(guard, 3)
    for name in ROBOTS:
        guard.answer(name, 3)
    assert guard.sim_time_ns(40 * MS) == 40 * MS
    assert guard.sim_time_ns(35 * MS) == 35 * MS  # an act that arrived at 35 ms


def test_an_act_that_came_within_the_lead_holds_nothing_when_the_loop_takes_it_late() -> None:
    """The loop sleeps until the next sense tick and only then takes the acts that came
    meanwhile: robot3's answer to tick 1 came at 18 ms, before its horizon of 20 ms (it had
    answered tick 0: that period ends at 10 ms, plus one period of lead).  The loop takes it
    at 27 ms.  Counted from when it came, it held nothing; a reading before the answer would
    have held the world for 7 ms."""
    taken, read_first = running_guard(), running_guard()
    for guard in (taken, read_first):
        publish_through(guard, 2)
        for name in ("robot1", "robot2"):
            guard.answer(name, 2)
        guard.answer("robot3", 0)
        assert guard.sim_time_ns(12 * MS) == 12 * MS
    now_ns, arrivals_ns = taken.take_answers(27 * MS, [("robot3", 1, 18 * MS)])
    assert (now_ns, arrivals_ns) == (27 * MS, [18 * MS])
    assert not taken.holding and taken.holds == 0 and taken.held_ns == 0
    # The order it replaces: the clock read at 27 ms before the answer is counted.
    assert read_first.sim_time_ns(27 * MS) == 20 * MS
    read_first.answer("robot3", 1)
    assert read_first.holds == 1 and read_first.held_ns == 7 * MS


def test_an_act_that_came_past_the_lead_holds_the_world_until_it_came() -> None:
    """robot3 answered tick 0 only (horizon 20 ms) and its answer to tick 1 came at 26 ms:
    the world was held from 20 to 26 ms of wall time, not until the loop took the act at
    33 ms, and the act came at 20 ms of simulated time."""
    guard = running_guard()
    publish_through(guard, 2)
    for name in ("robot1", "robot2"):
        guard.answer(name, 2)
    assert guard.sim_time_ns(12 * MS) == 12 * MS
    now_ns, arrivals_ns = guard.take_answers(
        33 * MS, [("robot1", 2, 15 * MS), ("robot3", 1, 26 * MS), ("robot2", 2, 30 * MS)]
    )
    assert arrivals_ns == [15 * MS, 20 * MS, 24 * MS]
    assert now_ns == 27 * MS
    assert guard.holds == 1 and guard.held_ns == 6 * MS
    assert guard.seats["robot3"].held_ns == 6 * MS and guard.seats["robot1"].held_ns == 0
    assert not guard.holding


def test_taking_a_pass_of_answers_is_reading_the_clock_at_each_of_them() -> None:
    """`take_answers` against a reading at each arrival, then the answer, then a reading now;
    passes with and without a hold, and an arrival before the last reading."""
    for answers_ms, now_ms in (
        ([("robot1", 2, 31), ("robot2", 2, 36), ("robot3", 2, 38)], 39),
        ([("robot1", 1, 35)], 70),
        ([("robot3", 3, 45), ("robot2", 3, 60), ("robot1", 3, 90)], 95),
        ([("robot1", 2, 25), ("robot2", 2, 29), ("robot3", 1, 31)], 40),
    ):
        one, each = running_guard(), running_guard()
        for guard in (one, each):
            publish_through(guard, 3)
            for name in ROBOTS:
                guard.answer(name, 1)
            assert guard.sim_time_ns(30 * MS) == 30 * MS
        answers = [(name, tick, m * MS) for name, tick, m in answers_ms]
        now_ns, arrivals_ns = one.take_answers(now_ms * MS, answers)
        expected = []
        for name, tick, arrival in answers:
            expected.append(each.sim_time_ns(arrival))
            each.answer(name, tick)
        assert arrivals_ns == expected
        assert now_ns == each.sim_time_ns(now_ms * MS)
        assert (one.holding, one.held_ns, one.holds) == (each.holding, each.held_ns, each.holds)
        assert one.seats == each.seats
    # The last pass: an act from before the last reading gets that reading's time at most.
    assert arrivals_ns[0] == 25 * MS


@pytest.mark.parametrize(
    ("period_ns", "hold_limit_ns", "lead"), [(0, MS, 1), (PERIOD_NS, 0, 1), (PERIOD_NS, MS, -1)]
)
def test_a_guard_needs_a_positive_period_and_hold_limit(
    period_ns: int, hold_limit_ns: int, lead: int
) -> None:
    with pytest.raises(ValueError, match="positive"):
        RealTimeGuard(ROBOTS, period_ns, hold_limit_ns, lead_periods=lead)


def test_the_real_time_factor_window_spans_the_last_wall_seconds() -> None:
    window = RealTimeFactorWindow(span_s=5.0)
    assert window.add(0.0, 0.0) is None
    for k in range(1, 11):  # 10 s at half speed, then 5 s at full speed
        factor = window.add(float(k), k * 0.5)
    assert factor == pytest.approx(0.5)
    for k in range(11, 16):
        factor = window.add(float(k), 5.0 + (k - 10))
    assert factor == pytest.approx(1.0)


def test_the_real_time_factor_window_starts_again_when_the_clock_jumps_back() -> None:
    window = RealTimeFactorWindow(span_s=5.0)
    window.add(0.0, 30.0)
    window.add(1.0, 31.0)
    assert window.add(2.0, 12.0) is None  # a world resumed from an older checkpoint
    assert window.add(3.0, 13.0) == pytest.approx(1.0)


@pytest.mark.parametrize("enabled", [True, False])
def test_the_blind_time_of_a_starved_robot_is_measured_and_bounded_by_the_guard(
    enabled: bool,
) -> None:
    """robot2 answers nothing for 200 ms of wall time, then catches up: with the guard the
    physics ran at most one period past its answered period; without, 200 ms."""
    guard = running_guard(enabled)
    run_world(guard, 0, 200, answering=("robot1", "robot3"))
    newest = guard.seats["robot1"].answered
    assert newest is not None
    guard.answer("robot2", newest)
    run_world(guard, 200, 300, answering=ROBOTS)
    blind_s = guard.stats().max_blind_s
    if enabled:
        assert blind_s["robot2"] == pytest.approx(PERIOD_NS / 1e9)
    else:
        assert blind_s["robot2"] == pytest.approx(0.19, abs=0.002)  # 200 ms - tick 0's period
    assert blind_s["robot1"] <= PERIOD_NS / 1e9


def test_sense_lateness_gives_nearest_rank_percentiles_the_maximum_and_late_ticks() -> None:
    lateness = SenseLateness(period_ns=10 * MS)
    for late_ms in range(1, 101):  # 1..100 ms, shuffled order must not matter
        lateness.record(((late_ms * 37) % 100 + 1) * MS)
    figures = lateness.as_dict()
    assert figures["sense_ticks"] == 100
    assert figures["sense_late_p50_ms"] == 50.0
    assert figures["sense_late_p99_ms"] == 99.0
    assert figures["sense_late_max_ms"] == 100.0
    assert figures["sense_late_by_a_period"] == 91  # 10..100 ms


def test_sense_lateness_clamps_an_early_reading_and_windows_its_percentiles() -> None:
    lateness = SenseLateness(period_ns=10 * MS, window=3)
    lateness.record(-5 * MS)  # the clock read before T(k): not late
    lateness.record(40 * MS)
    for _ in range(3):
        lateness.record(2 * MS)
    figures = lateness.as_dict()
    assert figures["sense_ticks"] == 5
    assert figures["sense_late_p99_ms"] == 2.0  # the 40 ms tick left the window
    assert figures["sense_late_max_ms"] == 40.0  # ...but not the run's maximum
    assert figures["sense_late_by_a_period"] == 1
    assert SenseLateness(period_ns=MS).as_dict()["sense_late_p50_ms"] is None

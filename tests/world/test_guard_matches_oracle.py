"""`RealTimeGuard.sim_time_ns` (one pass over the seats) against `OracleGuard` (one rule per
method, tests/world/guard_oracle.py): the same events in the same order must give the same
time at every call and leave every seat and counter the same.  A loop pass's acts
(`RealTimeGuard.take_answers`) must give what the oracle gives reading the clock at each
arrival, then taking the answer, then reading it now."""

from __future__ import annotations

import random
from dataclasses import asdict

import pytest

from tests.world.guard_oracle import OracleGuard
from world.realtime_guard import RealTimeGuard

MS = 1_000_000
PERIOD_NS = 10 * MS
ROBOTS = tuple(f"robot{i}" for i in range(1, 8))


def state(guard: RealTimeGuard) -> tuple[object, ...]:
    return (
        {name: asdict(seat) for name, seat in guard.seats.items()},
        guard.holding,
        guard.held_ns,
        guard.world_behind_ns,
        guard.holds,
        guard.longest_hold_ns,
        list(guard.new_lapses),
        guard.braked(),
        guard.waited_for(),
        guard.horizon_ns(),
        guard.stats(),
    )


PASSES_WITHOUT_A_HOLD: list[bool] = []
"""For each pass of acts driven, whether the guard found that no reading could hold (its
one-pass way) or read the clock at each act."""


def take_pass(guards: list[RealTimeGuard], rng: random.Random, mono_ns: int, published: int) -> int:
    """The acts of one loop pass, arrived since a little before the last reading up to the
    new `mono_ns` returned, mostly in order; the one-pass guard takes them at once, the oracle
    reads its clock at each arrival before the answer."""
    last_ns = guards[0]._last_mono_ns or 0
    now_ns = mono_ns + rng.randrange(0, 25 * MS)
    arrivals = sorted(
        max(0, rng.randrange(last_ns - 2 * MS, now_ns + 1)) for _ in range(rng.randrange(1, 9))
    )
    if rng.random() < 0.1:
        rng.shuffle(arrivals)
    behind = (0, 0, 1, 1, 2, 3, 8)
    answers = [
        (rng.choice(ROBOTS), published - rng.choice(behind) + rng.choice((0, 0, 1)), m)
        for m in arrivals
    ]
    PASSES_WITHOUT_A_HOLD.append(guards[0]._no_hold_before(now_ns, answers))
    one_pass = guards[0].take_answers(now_ns, answers)
    oracle = guards[1]
    arrivals_ns = []
    for name, tick, arrival in answers:
        arrivals_ns.append(oracle.sim_time_ns(arrival))
        oracle.answer(name, tick)
    assert one_pass == (oracle.sim_time_ns(now_ns), arrivals_ns)
    return now_ns


def drive(seed: int) -> RealTimeGuard:
    """Random joins, leaves, exemptions, answers, passes of acts and clock readings, the same
    on both guards, compared after every event; the one-pass guard at the end."""
    rng = random.Random(seed)
    enabled = seed % 8 != 7
    lead = rng.choice((0, 1, 2, 3))
    hold_limit_ns = rng.choice((15, 50, 500)) * MS
    guards = [
        cls(ROBOTS, PERIOD_NS, hold_limit_ns, enabled=enabled, lead_periods=lead)
        for cls in (RealTimeGuard, OracleGuard)
    ]
    tick0 = rng.choice((0, 0, 41))
    for guard in guards:
        guard.start(tick=tick0, tick_time_ns=tick0 * PERIOD_NS, sim_ns=tick0 * PERIOD_NS, mono_ns=0)
    mono_ns = 0
    published = tick0 - 1
    times: list[list[int]] = [[], []]
    for _ in range(2000):
        event = rng.random()
        name = rng.choice(ROBOTS)
        if event < 0.45:
            mono_ns += rng.randrange(0, 3 * MS)
            asked = mono_ns - rng.randrange(0, 2 * MS) if rng.random() < 0.1 else mono_ns
            for guard, seen in zip(guards, times, strict=True):
                seen.append(guard.sim_time_ns(max(asked, 0)))
            # The world publishes each tick once its time has come.
            while (published + 1) * PERIOD_NS <= guards[0]._sim_ns:
                published += 1
                for guard in guards:
                    guard.published(published)
        elif event < 0.6:
            mono_ns = take_pass(guards, rng, mono_ns, published)
        elif event < 0.85:
            # A robot answers a tick near the newest, sometimes far behind or ahead.
            tick = published - rng.choice((0, 0, 1, 2, 3, 8, 40)) + rng.choice((0, 0, 0, 1))
            for guard in guards:
                guard.answer(name, tick)
        elif event < 0.92:
            for guard in guards:
                guard.join(name)
        elif event < 0.96:
            for guard in guards:
                guard.leave(name)
        else:
            on = rng.random() < 0.5
            for guard in guards:
                guard.exempt_if(name, on)
        assert state(guards[0]) == state(guards[1])
    assert times[0] == times[1]
    assert len(times[0]) > 700
    return guards[0]


@pytest.mark.parametrize("seed", range(24))
def test_the_one_pass_clock_matches_the_rule_by_rule_clock(seed: int) -> None:
    guard = drive(seed)
    assert guard.holds > 0 or not guard.enabled


def test_the_random_passes_of_acts_go_both_ways() -> None:
    """Passes of acts where no reading could hold (one pass over the seats) and passes read
    one act at a time are both among those compared above."""
    PASSES_WITHOUT_A_HOLD.clear()
    for seed in range(6):
        drive(seed)
    assert PASSES_WITHOUT_A_HOLD.count(True) > 100
    assert PASSES_WITHOUT_A_HOLD.count(False) > 100


def test_the_random_runs_hold_lapse_and_find_the_world_behind() -> None:
    """The comparison above covers every branch of the clock: holds for robots, lapses after
    the hold limit, readmissions and the world's own lag."""
    guards = [drive(seed) for seed in range(3)]
    assert sum(s.lapses for g in guards for s in g.seats.values()) > 0
    assert sum(g.world_behind_ns for g in guards) > 0

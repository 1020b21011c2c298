"""Real-time starvation guard: simulated time never runs ahead of a robot the host starved.

A pure state machine (no Zenoh, no threads, time only as an argument), like the lockstep
barrier next door (world/lockstep.py); the world process (`world/runtime.py`, real-time loop)
feeds it what arrives and asks it what time it is.  DESIGN.md §7.1 ("Real-time factor") and
docs/robustness.md ("CPU starvation") say why.

**What a robot has answered.**  The world publishes sense tick k at simulation time
T(k) = T(k0) + (k - k0)·P (P the control period).  A real-time robot's act message carries the
tick of the newest sense message it had applied when it ran that control tick
(robot_firmware/tick_scheduler.py): a robot that answered tick a has acted on its pins at T(a),
for the control period [T(a), T(a + 1)).

**The rule.**  The world's simulated time never passes T(a_min + 1) + L·P, where a_min is the
oldest answer among the robots it waits for and L the lead in periods: at most L control
periods beyond the end of the period the slowest robot has answered.  A lead of zero would hold
the world every period for a robot whose tick falls late in the period.  The world's default is
two periods (`WorldConfig.starvation_lead_periods`): with one, the scheduling jitter of a host
that runs six robots, a world and a router on two cores held the world often enough to slow it
to 0.96 of real time while every robot still met 99.6 % of its deadlines; two periods (a robot
drives at most 20 ms on a command that old, 1.8 cm at full speed) are what such a host needs,
and a starved robot still exceeds them (docs/scale.md, "Real-time scale").

**The world's own lag.**  The same rule holds for the world itself, as if it were one more
seat whose answer is the newest sense tick it has published: simulated time never passes
T(p + 1) + L·P, p that tick.  A world that the host starves (its loop behind its own clock,
sense ticks late) is held like a starved robot, so its clock does not run away from its
physics and the sense ticks it owes.  Without it, a world behind by seconds saw every act
arrive seconds past its next sense tick; robots answering those late ticks never counted as
caught up, so no seat held the clock, and the world's work grew with the wall time it was
behind (docs/robustness.md, "A starved world").  The world never lapses: it is the simulator.

**The clock.**  Simulated time is the wall clock minus an offset, capped at that horizon:
`t_sim = min(mono - offset, horizon)`.  While the cap binds (the world is *held*), the offset
grows with the wall clock, so when the slow robot answers the run carries on from where it was
held: it slows down (real-time factor < 1) and never races to catch up.

**Seats** (one per robot):

| event                      | seat after it                                                  |
|----------------------------|----------------------------------------------------------------|
| `join` (token appears)     | live, lapsed: not waited for until its first answer that has    |
|                            | caught up                                                       |
| `leave` (token gone)       | not live: never waited for                                      |
| `exempt(on)`               | not waited for while on (a deliberate overload: `tick_slow`)    |
| `answer(tick)`             | answered = max(answered, tick), for a tick this world has       |
|                            | published (an answer to a tick it has not is another world's)   |
| caught up (lapsed seat     | waited for again: T(answered + 1) + P >= the world's time       |
|  whose answer is recent)   |                                                                 |
| held the world for longer  | lapsed: not waited for, and its body braked, until it catches  |
|  than `hold_limit_ns`      | up                                                              |

A frozen or dead robot therefore holds the world for at most `hold_limit_ns` of wall time
(the world's setting is at most the robots' liveliness lease, 1 s): a dead one until its token
goes (milliseconds after a kill), a frozen one until the limit or its lease, whichever is
first.  With the guard off, no seat is ever waited for and the clock is the plain wall clock.

**Real-time factor.**  `RealTimeFactorWindow` gives simulated seconds per wall second over the
last few wall seconds (the dashboard's live figure); the world's `real_time_factor` is the same
ratio since time started.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

NS_PER_S = 1_000_000_000
LEAD_PERIODS = 2
"""How many control periods simulated time may run beyond the slowest robot's answered one."""


@dataclass
class GuardSeat:
    """One robot's place in the guard (the table in the module docstring)."""

    live: bool = False
    lapsed: bool = True
    exempt: bool = False
    answered: int | None = None
    blocked_since_mono_ns: int | None = None
    """When this robot started holding the world (None: it does not hold it now)."""
    held_ns: int = 0
    """Wall time the world spent held for this robot."""
    lapses: int = 0
    max_blind_ns: int = 0
    """The longest simulated time ran past the end of the period this robot had answered,
    its body driven by a command that had not seen it (guard on or off)."""

    @property
    def waited_for(self) -> bool:
        return self.live and not self.exempt and not self.lapsed and self.answered is not None


@dataclass(frozen=True)
class GuardStats:
    """What the guard did, for summary.json."""

    enabled: bool
    lead_periods: int
    hold_limit_s: float
    held_s: float
    """Wall time during which simulated time stood still, waiting for a robot or for the
    world itself (`world_behind_s`)."""
    world_behind_s: float
    """The part of `held_s` when the world's own lag bound: its newest published sense tick
    was more than the lead behind its clock."""
    holds: int
    longest_hold_s: float
    held_for_s: dict[str, float]
    """Per robot: wall time the world was held for it (holds for two robots count for both)."""
    lapses: dict[str, int]
    """Per robot: how often it held the world past the limit and was no longer waited for."""
    max_blind_s: dict[str, float]
    """Per robot: the longest simulated time ran past the end of the period it had answered
    while its body was driven (with the guard on, at most the lead, one period, unless the
    robot was exempt)."""

    def as_dict(self) -> dict[str, object]:
        return {
            "enabled": self.enabled,
            "lead_periods": self.lead_periods,
            "hold_limit_s": self.hold_limit_s,
            "held_s": round(self.held_s, 6),
            "world_behind_s": round(self.world_behind_s, 6),
            "holds": self.holds,
            "longest_hold_s": round(self.longest_hold_s, 6),
            "held_for_s": {name: round(s, 6) for name, s in self.held_for_s.items()},
            "lapses": dict(self.lapses),
            "max_blind_s": {name: round(s, 6) for name, s in self.max_blind_s.items()},
        }


class RealTimeGuard:
    """The real-time world's clock, held back for starved robots (module docstring)."""

    def __init__(
        self,
        names: Sequence[str],
        period_ns: int,
        hold_limit_ns: int,
        enabled: bool = True,
        lead_periods: int = LEAD_PERIODS,
    ) -> None:
        if period_ns <= 0 or hold_limit_ns <= 0 or lead_periods < 0:
            raise ValueError(
                f"period and hold limit must be positive and the lead not negative: "
                f"{period_ns}, {hold_limit_ns}, {lead_periods}"
            )
        self.names = tuple(names)
        self.period_ns = period_ns
        self.hold_limit_ns = hold_limit_ns
        self.enabled = enabled
        self.lead_periods = lead_periods
        self.seats = {name: GuardSeat() for name in self.names}
        self._tick0 = 0
        self._tick0_ns = 0
        self._offset_ns = 0
        self._sim_ns = 0
        self._last_mono_ns: int | None = None
        self._published = -1
        self._hold_started_mono_ns: int | None = None
        self.holding = False
        """Whether the last `sim_time_ns` found the world held."""
        self.held_ns = 0
        self.world_behind_ns = 0
        self.holds = 0
        self.longest_hold_ns = 0
        self.new_lapses: list[tuple[str, int | None]] = []
        """Robots passed over since the world last looked, with the tick they had answered."""

    # -- the world's side ------------------------------------------------------------------

    def start(self, tick: int, tick_time_ns: int, sim_ns: int, mono_ns: int) -> None:
        """Time runs from simulation time `sim_ns` at wall time `mono_ns`; sense tick `tick`
        is (or was) due at `tick_time_ns`."""
        self._tick0, self._tick0_ns = tick, tick_time_ns
        self._offset_ns = mono_ns - sim_ns
        self._sim_ns = sim_ns
        self._last_mono_ns = mono_ns
        self._published = tick - 1

    def published(self, tick: int) -> None:
        """The world published sense tick `tick`."""
        self._published = max(self._published, tick)

    def tick_time_ns(self, tick: int) -> int:
        return self._tick0_ns + (tick - self._tick0) * self.period_ns

    def horizon_ns(self) -> int | None:
        """How far simulated time may run now (None: no limit): the lead beyond the slowest
        waited-for robot's answered period and beyond the world's own newest sense tick."""
        if not self.enabled:
            return None
        answers = [s.answered for s in self.seats.values() if s.waited_for]
        world_ns = self._world_horizon_ns()
        if not answers:
            return world_ns
        return min(self._seat_horizon_ns(min(a for a in answers if a is not None)), world_ns)

    def _world_horizon_ns(self) -> int:
        """The world's own seat: its newest published sense tick is its answer."""
        return self._seat_horizon_ns(self._published)

    def _seat_horizon_ns(self, answered: int) -> int:
        return self.tick_time_ns(answered + 1 + self.lead_periods)

    def take_answers(
        self, mono_ns: int, answers: Sequence[tuple[str, int, int]]
    ) -> tuple[int, list[int]]:
        """The acts a loop pass takes, each as (robot, tick it answered, wall instant it
        arrived), in arrival order: what a reading of the clock at each arrival followed by
        that robot's `answer`, then a reading at `mono_ns` (no earlier than any arrival), give.
        Returns the time at `mono_ns` and the simulation time of each arrival.

        An answer so counts from when it came, not from when the loop took it.  The real-time
        loop sleeps until the next sense tick and takes the acts that came meanwhile only
        then; read first, the clock would find a robot that answered within its lead holding
        the world, for as long as the loop woke late (docs/scale.md, "The world's intake").

        A reading is a pass over the seats.  When no reading up to `mono_ns` can hold (every
        horizon that could bind lies at or beyond the wall clock at `mono_ns`) and the
        arrivals come in order, the readings at the arrivals only move the clock on and touch
        the seats of the robots answering: one pass over the seats for the whole loop pass
        (docs/scale.md, "The world's loop at 18 robots").  tests/world/test_guard_matches_oracle.py
        checks both ways against readings one at a time."""
        if not self._no_hold_before(mono_ns, answers):
            arrivals_ns = []
            for name, tick, arrival_ns in answers:
                arrivals_ns.append(self.sim_time_ns(arrival_ns))
                self.answer(name, tick)
            return self.sim_time_ns(mono_ns), arrivals_ns
        offset_ns, period_ns, enabled = self._offset_ns, self.period_ns, self.enabled
        horizon0_ns = self._tick0_ns + (1 + self.lead_periods - self._tick0) * period_ns
        blind0_ns = -self._tick0_ns - (1 - self._tick0) * period_ns
        last_mono_ns, sim_ns = self._last_mono_ns, self._sim_ns
        seats = self.seats
        # Readings readmit lapsed robots that caught up (seldom any); none of them can hold.
        lapsed = [s for s in seats.values() if s.lapsed and s.live and s.answered is not None]
        arrivals_ns = []
        for name, tick, arrival_ns in answers:
            if last_mono_ns is not None and arrival_ns < last_mono_ns:
                arrivals_ns.append(min(sim_ns, arrival_ns - offset_ns))
            else:
                # Against the time of the reading before, as `sim_time_ns` readmits.
                for other in lapsed:
                    other_answered = other.answered
                    if (
                        other.lapsed
                        and other_answered is not None
                        and horizon0_ns + other_answered * period_ns >= sim_ns
                    ):
                        other.lapsed = False
                last_mono_ns = arrival_ns
                sim_ns = max(sim_ns, arrival_ns - offset_ns)
                arrivals_ns.append(sim_ns)
                # The blind time of the robot answering, up to its answer; the others' grows
                # to the last reading's.
                seat = seats[name]
                answered = seat.answered
                if (
                    seat.live
                    and answered is not None
                    and not (enabled and seat.lapsed and not seat.exempt)
                ):
                    blind_ns = sim_ns + blind0_ns - answered * period_ns
                    if blind_ns > seat.max_blind_ns:
                        seat.max_blind_ns = blind_ns
            self.answer(name, tick)
            seat = seats[name]
            if seat.lapsed and seat.live and seat.answered is not None and seat not in lapsed:
                lapsed.append(seat)
        self._last_mono_ns, self._sim_ns = last_mono_ns, sim_ns
        return self.sim_time_ns(mono_ns), arrivals_ns

    def _no_hold_before(self, mono_ns: int, answers: Sequence[tuple[str, int, int]]) -> bool:
        """Whether readings at the arrivals of `answers` (given in order) and at `mono_ns`
        cannot hold the world, whatever the answers change: the guard is off, or the world's
        own horizon and that of every robot that could be waited for by then, at the oldest
        tick it has answered in the meantime, lie at or beyond the wall clock at `mono_ns`."""
        last_mono_ns = self._last_mono_ns
        if last_mono_ns is None:
            return False
        previous_ns = last_mono_ns
        oldest: dict[str, int | None] = {}
        for name, tick, arrival_ns in answers:
            if arrival_ns >= previous_ns:
                previous_ns = arrival_ns
            elif previous_ns > last_mono_ns:
                return False  # out of order after a reading: read one at a time
            seat = self.seats[name]
            if name not in oldest:
                oldest[name] = seat.answered
            if oldest[name] is None and tick <= self._published:
                oldest[name] = tick
        if not self.enabled:
            return True
        wanted_ns = mono_ns - self._offset_ns
        period_ns = self.period_ns
        horizon0_ns = self._tick0_ns + (1 + self.lead_periods - self._tick0) * period_ns
        if horizon0_ns + self._published * period_ns < wanted_ns:
            return False
        sim_ns = self._sim_ns
        for name, seat in self.seats.items():
            answered = oldest.get(name, seat.answered)
            if answered is None or not seat.live or seat.exempt:
                continue
            horizon_ns = horizon0_ns + answered * period_ns
            if horizon_ns >= wanted_ns:
                continue
            # A lapsed robot that does not answer now and lies behind the clock already
            # stays lapsed: nothing readmits it before `mono_ns`.
            if seat.lapsed and name not in oldest and horizon_ns < sim_ns:
                continue
            return False
        return True

    def sim_time_ns(self, mono_ns: int) -> int:
        """The simulation time at wall time `mono_ns`: the wall clock, held back to the
        horizon.  A robot that has held the world for longer than the hold limit is no longer
        waited for.  An instant before the last one asked about gets the wall clock less the
        offset as it stands now, never later than the last time: the time it had then, unless
        the clock was held since, in which case an earlier one.

        The world's loop asks several times per control period, so this is one pass over the
        seats, then a second over those that were waited for, with the horizons as plain
        integers: in order, lapsed robots that caught up are waited for again, the robots that
        hold the world (and lapse after the hold limit) are found, the horizon is taken, and
        every seat's blind time is measured at the time given.  tests/world/guard_oracle.py
        keeps the same steps one method each, as the specification this is tested against."""
        if self._last_mono_ns is not None and mono_ns < self._last_mono_ns:
            return min(self._sim_ns, mono_ns - self._offset_ns)
        self._last_mono_ns = mono_ns
        period_ns = self.period_ns
        # A seat that answered tick a may let simulated time run to horizon0_ns + a * period.
        horizon0_ns = self._tick0_ns + (1 + self.lead_periods - self._tick0) * period_ns
        sim_ns = self._sim_ns
        wanted_ns = mono_ns - self._offset_ns
        world_ns = horizon0_ns + self._published * period_ns
        enabled = self.enabled
        # Lapsed robots that caught up are waited for again; the rest wait with their horizons.
        waited: list[tuple[str, GuardSeat, int]] = []
        binding_ns = min(world_ns, wanted_ns)
        for name, seat in self.seats.items():
            answered = seat.answered
            if answered is None or not seat.live:
                seat.blocked_since_mono_ns = None
                continue
            horizon = horizon0_ns + answered * period_ns
            if seat.lapsed and horizon >= sim_ns:
                seat.lapsed = False
            if not enabled or seat.exempt or seat.lapsed:
                seat.blocked_since_mono_ns = None
                continue
            waited.append((name, seat, horizon))
            if horizon < binding_ns:
                binding_ns = horizon
        binding_ns = max(binding_ns, sim_ns)
        # Who holds the world back from `wanted_ns` now (their horizon binds, or lies behind
        # the world's time), and not while the world's own lag binds before theirs does; those
        # that have held it for longer than the hold limit lapse.
        blockers: list[GuardSeat] = []
        horizon_ns = world_ns
        for name, seat, horizon in waited:
            if horizon >= wanted_ns or horizon > binding_ns or horizon >= world_ns:
                seat.blocked_since_mono_ns = None
            elif seat.blocked_since_mono_ns is None:
                seat.blocked_since_mono_ns = mono_ns
            elif mono_ns - seat.blocked_since_mono_ns > self.hold_limit_ns:
                seat.lapsed = True
                seat.lapses += 1
                seat.blocked_since_mono_ns = None
                self.new_lapses.append((name, seat.answered))
                continue
            if seat.blocked_since_mono_ns is not None:
                blockers.append(seat)
            if horizon < horizon_ns:
                horizon_ns = horizon
        if not enabled or wanted_ns <= horizon_ns:
            self.holding = False
            now_ns = self._sim_ns = max(sim_ns, wanted_ns)
        else:
            # Held: the wall time past the horizon is not simulated time; it moves the offset.
            now_ns = max(horizon_ns, sim_ns)
            slip_ns = wanted_ns - now_ns
            self._offset_ns += slip_ns
            self.held_ns += slip_ns
            if world_ns == horizon_ns:
                self.world_behind_ns += slip_ns
            for seat in blockers:
                seat.held_ns += slip_ns
            if not self.holding:
                self.holding = True
                self.holds += 1
                self._hold_started_mono_ns = mono_ns - slip_ns
            assert self._hold_started_mono_ns is not None
            self.longest_hold_ns = max(self.longest_hold_ns, mono_ns - self._hold_started_mono_ns)
            self._sim_ns = now_ns
        # How long each robot's body has driven on a command that had not seen it.  A braked
        # one (lapsed, not exempt, guard on) is not driving.
        blind0_ns = now_ns - self._tick0_ns - (1 - self._tick0) * period_ns
        for seat in self.seats.values():
            answered = seat.answered
            if (
                answered is not None
                and seat.live
                and not (enabled and seat.lapsed and not seat.exempt)
                and blind0_ns - answered * period_ns > seat.max_blind_ns
            ):
                seat.max_blind_ns = blind0_ns - answered * period_ns
        return now_ns

    # -- the robots' side ------------------------------------------------------------------

    def join(self, name: str) -> None:
        """The robot's token appeared: a clean seat, waited for once it answers in time."""
        self.seats[name] = self._clean_seat(name, live=True)

    def leave(self, name: str) -> None:
        self.seats[name] = self._clean_seat(name, live=False)

    def _clean_seat(self, name: str, live: bool) -> GuardSeat:
        """A new seat that keeps the old one's exemption and counters."""
        seat = self.seats[name]
        return GuardSeat(
            live=live,
            exempt=seat.exempt,
            held_ns=seat.held_ns,
            lapses=seat.lapses,
            max_blind_ns=seat.max_blind_ns,
        )

    def exempt(self, name: str, on: bool) -> None:
        """A deliberate overload of this robot (`tick_slow`) is a fault to watch, not host
        starvation to hide: while on, the world does not wait for it.  Off again, it is waited
        for once it has caught up."""
        seat = self.seats[name]
        seat.exempt = on
        seat.lapsed = True
        seat.blocked_since_mono_ns = None

    def exempt_if(self, name: str, on: bool) -> None:
        """`exempt`, when that changes anything (the robot's telemetry says it every time)."""
        if self.seats[name].exempt != on:
            self.exempt(name, on)

    def answer(self, name: str, tick: int) -> None:
        """The robot's act message: it had applied sense tick `tick`."""
        if tick > self._published:
            return
        seat = self.seats[name]
        seat.answered = tick if seat.answered is None else max(seat.answered, tick)

    # -- what the world reads --------------------------------------------------------------

    def braked(self) -> frozenset[str]:
        """Live robots the world has stopped waiting for because they held it too long (or
        have not answered since they joined): their bodies are braked until they catch up."""
        if not self.enabled:
            return frozenset()
        return frozenset(n for n, s in self.seats.items() if s.live and s.lapsed and not s.exempt)

    def waited_for(self) -> frozenset[str]:
        return frozenset(n for n, s in self.seats.items() if self.enabled and s.waited_for)

    def stats(self) -> GuardStats:
        return GuardStats(
            enabled=self.enabled,
            lead_periods=self.lead_periods,
            hold_limit_s=self.hold_limit_ns / NS_PER_S,
            held_s=self.held_ns / NS_PER_S,
            world_behind_s=self.world_behind_ns / NS_PER_S,
            holds=self.holds,
            longest_hold_s=self.longest_hold_ns / NS_PER_S,
            held_for_s={n: s.held_ns / NS_PER_S for n, s in self.seats.items()},
            lapses={n: s.lapses for n, s in self.seats.items()},
            max_blind_s={n: s.max_blind_ns / NS_PER_S for n, s in self.seats.items()},
        )


@dataclass
class RealTimeFactorWindow:
    """Simulated seconds per wall second over the last `span_s` of wall time."""

    span_s: float = 5.0
    samples: deque[tuple[float, float]] = field(default_factory=deque)

    def add(self, wall_s: float, sim_s: float) -> float | None:
        """Record that simulated time was `sim_s` at wall time `wall_s`; the factor over the
        window (None until it spans some wall time, or after the simulated clock jumped back:
        a restarted world)."""
        samples = self.samples
        if samples and sim_s < samples[-1][1]:
            samples.clear()
        samples.append((wall_s, sim_s))
        while len(samples) > 1 and samples[1][0] <= wall_s - self.span_s:
            samples.popleft()
        wall0_s, sim0_s = samples[0]
        if wall_s - wall0_s <= 0.0:
            return None
        return (sim_s - sim0_s) / (wall_s - wall0_s)


@dataclass
class SenseLateness:
    """The world loop's own lag: how late a sense tick's messages left against its due time
    T(k), in real time.

    The loop sees that the guard's clock (`RealTimeGuard.sim_time_ns`) has reached T(k): it
    was late by the clock's reading minus T(k) then, plus the wall time from that check to the
    messages' departure (the physics catching up, the tick's faults, the frames due).  A hold
    for a starved robot stops that clock, so it does not count here (it is in `GuardStats`):
    this is the lag the world's own work made.  A
    loop that keeps up publishes within a fraction of a period; one that falls behind its
    physics and relaying shows it here before the real-time factor drops.  Percentiles are over
    the last `window` ticks, the maximum and the count of ticks late by a period or more over
    all of them."""

    period_ns: int
    window: int = 20_000
    ticks: int = 0
    max_ns: int = 0
    late_by_a_period: int = 0
    recent_ns: deque[int] = field(init=False)

    def __post_init__(self) -> None:
        self.recent_ns = deque(maxlen=self.window)

    def record(self, late_ns: int) -> None:
        """Tick k's messages left when the world's clock read T(k) + `late_ns`."""
        late_ns = max(late_ns, 0)
        self.ticks += 1
        self.recent_ns.append(late_ns)
        if late_ns > self.max_ns:
            self.max_ns = late_ns
        if late_ns >= self.period_ns:
            self.late_by_a_period += 1

    def as_dict(self) -> dict[str, object]:
        """The figures for summary.json (`world_loop`; docs/summary-schema.md)."""
        recent = self.recent_ns

        def percentile_ms(q: float) -> float | None:
            if not recent:
                return None
            # The nearest rank, as numpy's inverted CDF gives it (no interpolation).
            return round(float(np.percentile(recent, 100 * q, method="inverted_cdf")) / 1e6, 3)

        return {
            "sense_ticks": self.ticks,
            "sense_late_p50_ms": percentile_ms(0.50),
            "sense_late_p99_ms": percentile_ms(0.99),
            "sense_late_max_ms": round(self.max_ns / 1e6, 3),
            "sense_late_by_a_period": self.late_by_a_period,
        }

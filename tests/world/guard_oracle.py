"""The real-time guard's clock one rule at a time: the specification `RealTimeGuard.sim_time_ns`
(world/realtime_guard.py) is tested against (tests/world/test_guard_matches_oracle.py).

`OracleGuard` asks each rule of the module docstring in its own method, each over every seat:
lapsed robots that caught up are waited for again, the robots holding the world are found (and
lapse after the hold limit), the horizon is the lead beyond the slowest answer and the world's
own newest sense tick, and the blind time is measured at the time given."""

from __future__ import annotations

from world.realtime_guard import RealTimeGuard


class OracleGuard(RealTimeGuard):
    def sim_time_ns(self, mono_ns: int) -> int:
        if self._last_mono_ns is not None and mono_ns < self._last_mono_ns:
            return min(self._sim_ns, mono_ns - self._offset_ns)
        self._last_mono_ns = mono_ns
        self._readmit_caught_up()
        wanted_ns = mono_ns - self._offset_ns
        blockers = self._blockers(wanted_ns, mono_ns)
        horizon = self.horizon_ns()
        if horizon is None or wanted_ns <= horizon:
            self.holding = False
            self._sim_ns = max(self._sim_ns, wanted_ns)
            self._measure_blind_time()
            return self._sim_ns
        now_ns = max(horizon, self._sim_ns)
        slip_ns = wanted_ns - now_ns
        self._offset_ns += slip_ns
        self.held_ns += slip_ns
        if self._world_horizon_ns() == horizon:
            self.world_behind_ns += slip_ns
        for name in blockers:
            self.seats[name].held_ns += slip_ns
        if not self.holding:
            self.holding = True
            self.holds += 1
            self._hold_started_mono_ns = mono_ns - slip_ns
        assert self._hold_started_mono_ns is not None
        self.longest_hold_ns = max(self.longest_hold_ns, mono_ns - self._hold_started_mono_ns)
        self._sim_ns = now_ns
        self._measure_blind_time()
        return now_ns

    def _measure_blind_time(self) -> None:
        braked = self.braked()
        for name, seat in self.seats.items():
            if seat.live and seat.answered is not None and name not in braked:
                blind_ns = self._sim_ns - self.tick_time_ns(seat.answered + 1)
                seat.max_blind_ns = max(seat.max_blind_ns, blind_ns)

    def _blockers(self, wanted_ns: int, mono_ns: int) -> list[str]:
        """Waited-for robots whose horizon binds (or lies behind the world's time), unless the
        world's own lag binds first; those holding the world past the hold limit lapse."""
        horizons = {
            name: self._seat_horizon_ns(seat.answered)
            for name, seat in self.seats.items()
            if self.enabled and seat.waited_for and seat.answered is not None
        }
        world_ns = self._world_horizon_ns()
        binding_ns = max(min(*horizons.values(), world_ns, wanted_ns), self._sim_ns)
        blockers = []
        for name, seat in self.seats.items():
            horizon = horizons.get(name)
            if (
                horizon is None
                or horizon >= wanted_ns
                or horizon > binding_ns
                or horizon >= world_ns
            ):
                seat.blocked_since_mono_ns = None
                continue
            if seat.blocked_since_mono_ns is None:
                seat.blocked_since_mono_ns = mono_ns
            if mono_ns - seat.blocked_since_mono_ns > self.hold_limit_ns:
                seat.lapsed = True
                seat.lapses += 1
                seat.blocked_since_mono_ns = None
                self.new_lapses.append((name, seat.answered))
                continue
            blockers.append(name)
        return blockers

    def _readmit_caught_up(self) -> None:
        for seat in self.seats.values():
            if (
                seat.lapsed
                and seat.live
                and seat.answered is not None
                and self._seat_horizon_ns(seat.answered) >= self._sim_ns
            ):
                seat.lapsed = False

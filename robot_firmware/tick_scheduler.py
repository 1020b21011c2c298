"""When the robot runs its next control tick, and at what simulation time: a pure state machine.

The robot process (`robot_firmware/runtime.py`) tells the scheduler what arrived (`sensed`: a
sense message was applied to the pins) and asks it what to do (`poll`: wait, or run a tick now);
after a real-time tick it reports how long the tick took (`finished`).  Time enters only as
arguments (monotonic nanoseconds), so every transition is tested without Zenoh or a clock
(tests/test_tick_scheduler.py).

Two clock modes, chosen by the world's sense messages:

* **real time**: a tick every control period on the monotonic clock.  The simulation time of a
  tick is that of the newest sense message plus the monotonic time since it arrived, so frame
  timestamps of different robots compare.  A tick that starts more than a period late, or ends
  after its period, is a deadline miss; a loop that falls more than five periods behind starts
  its deadlines afresh instead of running a burst of late ticks.
* **lockstep**: one tick per sense message, at the message's simulation time, answered with its
  tick number; it runs once the radio frames the message announces have arrived.  After a
  (re)join two ticks may be queued: only the newest is answered.

Until the first sense message there is no time, and no tick runs.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

NS_PER_S = 1_000_000_000
IDLE_WAIT_S = 0.05
"""How long to sleep when nothing can happen before new input arrives."""
RESYNC_PERIODS = 5
"""A real-time loop this many periods behind starts its deadlines afresh."""


@dataclass(frozen=True)
class Wait:
    """Sleep up to `timeout_s`, or until new input arrives."""

    timeout_s: float


@dataclass(frozen=True)
class RunTick:
    """Run a control tick now, at simulation time `sim_time_ns`, answering `tick` (0 in real
    time)."""

    sim_time_ns: int
    tick: int
    started_mono_ns: int


@dataclass(frozen=True)
class _Sensed:
    t_ns: int
    tick: int
    radio_frames: int
    arrival_mono_ns: int


@dataclass
class LoopTiming:
    """Control-loop period jitter and deadline misses, over a bounded window of periods."""

    period_ns: int
    ticks: int = 0
    deadline_misses: int = 0
    jitter_ns: deque[int] = field(default_factory=lambda: deque(maxlen=20_000))
    recent_miss_ticks: deque[int] = field(default_factory=lambda: deque(maxlen=10))

    def record(self, period_ns: int, overran: bool) -> None:
        self.ticks += 1
        self.jitter_ns.append(abs(period_ns - self.period_ns))
        if overran:
            self.deadline_misses += 1
            self.recent_miss_ticks.append(self.ticks)

    def jitter_p99_ms(self) -> float | None:
        return float(np.percentile(self.jitter_ns, 99)) / 1e6 if self.jitter_ns else None


class TickScheduler:
    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.timing = LoopTiming(period_ns)
        self.lockstep = False
        self._last: _Sensed | None = None
        self._pending: _Sensed | None = None
        self._next_deadline_ns = 0
        self._last_start_ns: int | None = None

    @property
    def has_time(self) -> bool:
        return self._last is not None

    def sensed(
        self, t_ns: int, tick: int, lockstep: bool, radio_frames: int, arrival_mono_ns: int
    ) -> None:
        """A sense message was applied to the pins (messages in arrival order)."""
        sensed = _Sensed(t_ns, tick, radio_frames, arrival_mono_ns)
        if self._last is None:
            self._next_deadline_ns = arrival_mono_ns
        self._last = sensed
        self.lockstep = lockstep
        self._pending = sensed if lockstep else None

    def sim_time_ns(self, mono_now_ns: int) -> int | None:
        """The simulation time now, extrapolated from the newest sense message; None before."""
        if self._last is None:
            return None
        return self._last.t_ns + (mono_now_ns - self._last.arrival_mono_ns)

    def poll(self, mono_now_ns: int, frames_queued: int) -> Wait | RunTick:
        if self._last is None:
            return Wait(IDLE_WAIT_S)
        if self.lockstep:
            pending = self._pending
            if pending is None or frames_queued < pending.radio_frames:
                return Wait(IDLE_WAIT_S)
            self._pending = None
            return RunTick(pending.t_ns, pending.tick, mono_now_ns)
        if mono_now_ns < self._next_deadline_ns:
            return Wait((self._next_deadline_ns - mono_now_ns) / NS_PER_S)
        sim_now = self.sim_time_ns(mono_now_ns)
        assert sim_now is not None
        return RunTick(sim_now, 0, mono_now_ns)

    def finished(self, tick: RunTick, end_mono_ns: int) -> None:
        """A real-time tick ended: record its timing and set the next deadline."""
        if self.lockstep:
            return
        start = tick.started_mono_ns
        deadline = self._next_deadline_ns
        if self._last_start_ns is not None:
            late = start - deadline > self.period_ns
            self.timing.record(
                start - self._last_start_ns, late or end_mono_ns > deadline + self.period_ns
            )
        self._last_start_ns = start
        self._next_deadline_ns = deadline + self.period_ns
        if end_mono_ns - self._next_deadline_ns > RESYNC_PERIODS * self.period_ns:
            self._next_deadline_ns = end_mono_ns + self.period_ns

"""When the robot runs its next control tick, and at what simulation time: a pure state machine.

The robot process (`robot_firmware/runtime.py`) tells the scheduler what arrived (`sensed`: a
sense message was applied to the pins) and asks it what to do (`poll`: wait, or run a tick now);
after a real-time tick it reports how long the tick took (`finished`).  Time enters only as
arguments (monotonic nanoseconds), so every transition is tested without Zenoh or a clock
(tests/test_tick_scheduler.py).

Two clock modes, chosen by the world's sense messages:

* **real time**: a tick every control period of *simulation* time, when the world's sense
  message for it has come: the loop follows the world's clock and never runs ahead of it, so
  when the world runs slower than the wall clock (it holds its time for a starved robot,
  world/realtime_guard.py) each tick still covers one period of the world's time, the fixed
  step of the control law.  The simulation time of a tick is that of the newest sense message
  plus the monotonic time since it arrived (at most one period).  The loop's deadlines are
  grid points of simulation time one period apart, mapped to the monotonic clock by the newest
  sense message: a tick that starts more than a period after its deadline, or ends more than
  a period after it, is a deadline miss.  Grid points that passed while a tick ran are
  skipped (no burst of late ticks), but the newest message is always answered.  A real-time
  tick answers the tick number of the newest sense message (the world's starvation guard reads
  it from the act message).  A sense message that repeats the newest one (same tick and time:
  the world holds its time) only says that the world is there.
  When no sense message has arrived for `sense_timeout_ns` (the world died, or this process
  was frozen), the scheduler stops controlling: every period it answers `SafeStop` instead of
  a tick, and the firmware holds the motors off and stops kicking the watchdog.  The first
  tick after sense messages come back (or after any gap in their arrival longer than the
  timeout) is marked `resumed`, so the firmware drops what went stale, and its deadlines
  start afresh from the message.
* **lockstep**: one tick per sense message, at the message's simulation time, answered with its
  tick number; it runs once the radio frames the message announces have arrived.  After a
  (re)join two ticks may be queued: only the newest is answered.

A sense message of a new world epoch (the world restarted, from a checkpoint or from nothing)
moves the loop's time to the message's, backwards or forwards, at once: the next tick runs on
the new time (in real time: deadlines afresh from its arrival) and is marked `new_epoch`.

Until the first sense message there is no time, and no tick runs.  Lockstep has no sense
time-out: without the world no simulated time passes, and no tick means no control.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

NS_PER_S = 1_000_000_000
IDLE_WAIT_S = 0.05
"""How long to sleep when nothing can happen before new input arrives."""
SENSE_TIMEOUT_PERIODS = 10
"""Default sense time-out, in control periods (100 ms at 100 Hz)."""
STALL_NS = 500_000_000
"""A loop that comes round this much later than it meant to was stalled (0.5 s)."""
TOKEN_SETTLE_NS = 2_000_000_000
"""How long after a stall the peers' liveliness tokens do not count (2 s)."""


@dataclass(frozen=True)
class Wait:
    """Sleep up to `timeout_s`, or until new input arrives."""

    timeout_s: float


@dataclass(frozen=True)
class RunTick:
    """Run a control tick now, at simulation time `sim_time_ns`, answering `tick` (in real
    time, the newest sense message's)."""

    sim_time_ns: int
    tick: int
    started_mono_ns: int
    resumed: bool = False
    """The first tick after a safe stop or a gap in the sense messages: state from before the
    gap is stale."""
    new_epoch: bool = False
    """The first tick of a new world epoch (the world restarted; its clock may have jumped
    backwards or forwards): every time-stamped state from before it is void."""


@dataclass(frozen=True)
class SafeStop:
    """No sense message for the sense time-out: motors off, no watchdog kick, no control.

    Answered once a period while it lasts; `sim_time_ns` is the extrapolated simulation time
    (the fabric keeps running, so its watchdog expires), `entered` is True the first time."""

    sim_time_ns: int
    started_mono_ns: int
    entered: bool


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


@dataclass
class LoopStallWatch:
    """Whether the robot process's own loop stalled (frozen by SIGSTOP, or starved of CPU).

    A process frozen for longer than its liveliness lease finds, when continued, that the router
    dropped its session: as it reconnects, every peer's token goes and comes back, while the
    messages queued before the freeze are still being read.  A robot that counted those tokens
    would take itself for the last one left and lead a term of its own.  So for `settle_ns`
    after a stall the tokens do not count (`settling`): frames alone decide who is live, as in
    lockstep (robot_firmware/leadership.py).  The loop says when it means to come round again
    (`due`); coming round more than `stall_ns` later is a stall."""

    stall_ns: int = STALL_NS
    settle_ns: int = TOKEN_SETTLE_NS
    stalls: int = field(init=False, default=0)
    _due_ns: int | None = field(init=False, default=None)
    _settled_ns: int | None = field(init=False, default=None)

    def due(self, due_mono_ns: int) -> None:
        """The loop means to come round again by `due_mono_ns`."""
        self._due_ns = due_mono_ns

    def came_round(self, now_mono_ns: int) -> int:
        """The loop came round at `now_mono_ns`: how late it was, when that is a stall (else
        0); a stall starts the settling time."""
        late_ns = 0 if self._due_ns is None else now_mono_ns - self._due_ns
        if late_ns <= self.stall_ns:
            return 0
        self.stalls += 1
        self._settled_ns = now_mono_ns + self.settle_ns
        return late_ns

    def settling(self, now_mono_ns: int) -> bool:
        """Whether the peers' tokens are not to count yet (within `settle_ns` of a stall)."""
        return self._settled_ns is not None and now_mono_ns < self._settled_ns


class TickScheduler:
    def __init__(self, period_ns: int, sense_timeout_ns: int | None = None) -> None:
        """sense_timeout_ns: how long without a sense message before a real-time loop stops
        safely; `SENSE_TIMEOUT_PERIODS` periods when None."""
        if sense_timeout_ns is None:
            sense_timeout_ns = SENSE_TIMEOUT_PERIODS * period_ns
        if period_ns <= 0 or sense_timeout_ns <= 0:
            raise ValueError(
                f"period and sense time-out must be positive: {period_ns}, {sense_timeout_ns}"
            )
        self.period_ns = period_ns
        self.sense_timeout_ns = sense_timeout_ns
        self.timing = LoopTiming(period_ns)
        self.lockstep = False
        self.safe_stopped = False
        """Whether the loop is in a safe stop now."""
        self.safe_stops = 0
        """Safe stops entered since start."""
        self._last: _Sensed | None = None
        self._heard_mono_ns = 0
        """Arrival of the newest sense message, a repeat included (for the time-out)."""
        self._pending: _Sensed | None = None
        self._due_sim_ns = 0
        """Real time: the simulation time the next tick is due at (a grid point)."""
        self._free_mono_ns: int | None = None
        """When the last tick ended: grid points before it are skipped."""
        self._tick_deadline_ns = 0
        """The monotonic deadline of the tick handed out last."""
        self._last_tick_sim_ns: int | None = None
        self._next_stop_ns = 0
        """When the next safe-stop period is due (monotonic)."""
        self._resume = False
        self.epoch: int | None = None
        """The world epoch of the newest sense message."""
        self.epoch_changes = 0
        """New world epochs seen after the first sense message."""
        self._new_epoch = False

    @property
    def has_time(self) -> bool:
        return self._last is not None

    @property
    def awaits_frames(self) -> bool:
        """Lockstep: the newest sense message is applied and its tick waits for the radio
        frames it announced.  Only then does a frame's arrival need to wake the loop: frames
        that come before their sense message are counted when it comes."""
        return self._pending is not None and self._pending.radio_frames > 0

    def sensed(
        self,
        t_ns: int,
        tick: int,
        lockstep: bool,
        radio_frames: int,
        arrival_mono_ns: int,
        epoch: int = 0,
    ) -> None:
        """A sense message was applied to the pins (messages in arrival order).

        A message of another world epoch than the previous one re-synchronises the loop to
        its time, wherever that is (the next tick is `new_epoch` and `resumed`)."""
        sensed = _Sensed(t_ns, tick, radio_frames, arrival_mono_ns)
        previous = self._last
        new_epoch = previous is not None and epoch != self.epoch
        self.epoch = epoch
        if new_epoch:
            self.epoch_changes += 1
            self._new_epoch = True
        gap = (
            previous is not None
            and not lockstep
            and arrival_mono_ns - self._heard_mono_ns > self.sense_timeout_ns
        )
        self._heard_mono_ns = arrival_mono_ns
        if previous is None:
            self._start_grid(t_ns)
        elif new_epoch or self.safe_stopped or gap:
            self._start_grid(t_ns)  # start afresh: no burst of late ticks
            self._resume = True
            self.safe_stopped = False
        elif not lockstep and not self.lockstep and (tick, t_ns) == (previous.tick, previous.t_ns):
            return  # a repeat: the world is holding its time, and is there
        elif lockstep != self.lockstep:
            self._start_grid(t_ns)
        self._last = sensed
        self.lockstep = lockstep
        self._pending = sensed if lockstep else None

    def _start_grid(self, t_ns: int) -> None:
        self._due_sim_ns = t_ns
        self._free_mono_ns = None
        self._last_tick_sim_ns = None

    def _extrapolated_ns(self, mono_now_ns: int) -> int:
        assert self._last is not None
        return self._last.t_ns + (mono_now_ns - self._last.arrival_mono_ns)

    def _world_time_ns(self, mono_now_ns: int) -> int:
        """Extrapolated from the newest sense message, at most one period past it."""
        assert self._last is not None
        return min(self._extrapolated_ns(mono_now_ns), self._last.t_ns + self.period_ns)

    def sim_time_ns(self, mono_now_ns: int) -> int | None:
        """The simulation time now, extrapolated from the newest sense message (in real time at
        most one period past it, unless in a safe stop); None before the first."""
        if self._last is None:
            return None
        if self.lockstep or self.safe_stopped:
            return self._extrapolated_ns(mono_now_ns)
        return self._world_time_ns(mono_now_ns)

    def poll(self, mono_now_ns: int, frames_queued: int) -> Wait | RunTick | SafeStop:
        if self._last is None:
            return Wait(IDLE_WAIT_S)
        if self.lockstep:
            pending = self._pending
            if pending is None or frames_queued < pending.radio_frames:
                return Wait(IDLE_WAIT_S)
            self._pending = None
            resumed, self._resume = self._resume, False
            new_epoch, self._new_epoch = self._new_epoch, False
            return RunTick(pending.t_ns, pending.tick, mono_now_ns, resumed, new_epoch)
        silent_ns = mono_now_ns - self._heard_mono_ns
        if silent_ns > self.sense_timeout_ns:
            return self._safe_stop(mono_now_ns)
        last = self._last
        self._skip_passed_grid_points()
        if self._due_sim_ns > last.t_ns:
            # The world has not reached the next grid point yet: wait for its next message.
            until_timeout_s = (self.sense_timeout_ns - silent_ns) / NS_PER_S
            return Wait(min(IDLE_WAIT_S, max(until_timeout_s, 0.0) + 1e-4))
        deadline_ns = last.arrival_mono_ns + (self._due_sim_ns - last.t_ns)
        if mono_now_ns < deadline_ns:  # only for arrivals stamped after this poll's clock
            return Wait((deadline_ns - mono_now_ns) / NS_PER_S)
        self._tick_deadline_ns = deadline_ns
        resumed, self._resume = self._resume, False
        new_epoch, self._new_epoch = self._new_epoch, False
        return RunTick(self._world_time_ns(mono_now_ns), last.tick, mono_now_ns, resumed, new_epoch)

    def _skip_passed_grid_points(self) -> None:
        """The next tick is due at the first grid point after the last tick ended (as the
        newest sense message maps that instant to simulation time), but never later than the
        grid point of the newest message: that one is answered, late or not (the world may be
        holding its time for this very answer)."""
        if self._free_mono_ns is None or self._last is None:
            return
        free_sim_ns = self._world_time_ns(self._free_mono_ns)
        self._free_mono_ns = None
        if free_sim_ns < self._due_sim_ns:
            return
        passed = (free_sim_ns - self._due_sim_ns) // self.period_ns + 1
        newest = (self._last.t_ns - self._due_sim_ns) // self.period_ns
        self._due_sim_ns += max(min(passed, newest), 0) * self.period_ns

    def _safe_stop(self, mono_now_ns: int) -> Wait | SafeStop:
        entered = not self.safe_stopped
        if entered:
            self.safe_stopped = True
            self.safe_stops += 1
            self._next_stop_ns = mono_now_ns
        if mono_now_ns < self._next_stop_ns:
            return Wait((self._next_stop_ns - mono_now_ns) / NS_PER_S)
        return SafeStop(self._extrapolated_ns(mono_now_ns), mono_now_ns, entered)

    def finished(self, tick: RunTick | SafeStop, end_mono_ns: int) -> None:
        """A real-time tick (or safe-stop period) ended: record its timing and set the next
        deadline.  Safe-stop periods are not control ticks and leave the timing alone."""
        if self.lockstep:
            return
        if isinstance(tick, SafeStop):
            self._last_tick_sim_ns = None
            self._next_stop_ns = max(self._next_stop_ns, end_mono_ns) + self.period_ns
            return
        deadline = self._tick_deadline_ns
        if self._last_tick_sim_ns is not None:
            late = tick.started_mono_ns - deadline > self.period_ns
            self.timing.record(
                tick.sim_time_ns - self._last_tick_sim_ns,
                late or end_mono_ns > deadline + self.period_ns,
            )
        self._last_tick_sim_ns = tick.sim_time_ns
        # The first grid point after the time this tick ran at.
        ran_periods = max(tick.sim_time_ns - self._due_sim_ns, 0) // self.period_ns
        self._due_sim_ns += (ran_periods + 1) * self.period_ns
        self._free_mono_ns = end_mono_ns

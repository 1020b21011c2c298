"""Lockstep clock: the barrier that waits for every live robot each tick, and the pacer.

Both are pure state machines: no Zenoh, no threads, and time only as an argument, so every
transition is tested without a network (tests/world/test_lockstep.py).  The world process
(`world/runtime.py`) feeds them what arrives and asks them what to do.

**Barrier.**  Per control period the world publishes tick k's sense messages, then waits until
every live robot has answered tick k with its act message *and* the radio frames that act
announced have arrived.  Each robot has a seat:

| event                     | seat after it                                                 |
|---------------------------|---------------------------------------------------------------|
| `join` (token appears)    | live; owes nothing before tick k+1 (tick k's sense message may |
|                           | have gone out before it listened); frames owed reset           |
| `leave` (token gone)      | not live: never waited for; frames owed reset                  |
| `start` (time starts)     | robots that joined before time started owe tick 0 already      |
| `act(tick, frames)`       | last act tick = tick; frames owed += frames                    |
| `frame`                   | frames owed -= 1                                               |
| `excuse` (owed the tick   | still live; owes nothing before tick k+1; frames owed reset:   |
|  past the answer time-out)| the tick goes on without it (a message to or from it was lost) |
| `resume` (world restarted | tick = the checkpoint's; every seat not live until its token   |
|  from a checkpoint)       | is seen again (`join`)                                         |

A live seat owes tick k when k >= its first owed tick and either its last act is older than k
or frames it announced are still to come.  The tick completes when no live seat owes it.

**Lost messages.**  A live robot that does not answer is waited for; but a message can be lost
without the robot dying: a process continued after a freeze longer than its liveliness lease
reconnects to the router, and until its subscriptions and the world's are declared again on
both sides, the sense message or radio frames sent to it, or the act and frames it sends, go
nowhere.  Then both sides would wait for ever, each for the other's message.  So the world
excuses a seat that has owed the tick for longer than its answer time-out (wall time,
`WorldConfig.lockstep_answer_timeout_s`): it goes on without that answer and waits for the
robot again from the next tick, whose sense message the robot hears.  A run in which no
message is lost never reaches the time-out, so it replays exactly as before.

**Pacer.**  With `max_speed` set, holds ticks back so simulated time runs at most `max_speed`
times the wall clock; a run that falls behind carries on at the same pace from where it is.

**Profile.**  Where a lockstep tick's wall time goes, phase by phase (`TICK_PHASES`), and how
long each robot took from the tick's sense message going out to its act message arriving (two
router hops and the robot's own receive, tick and act): the world's `admin/world/status`
reports it and bench/swarm_runtime.py prints it.  It only observes: nothing in it decides
anything, so a run's results do not depend on it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

NS_PER_S = 1_000_000_000
TICK_PHASES = ("boundary", "sense", "metrics", "wait_acts", "gather", "step", "after")
"""A lockstep tick in order: the tick boundary (queued input, telemetry due, faults); radio
frames due, sense and clock messages encoded and published; the metrics sample of the bodies as
they are (while the robots compute); waiting until every live robot has answered (acts and
announced frames); the last input drained and frames handed to the radio medium; the physics
step; truth, checkpoint and summary."""


@dataclass
class Seat:
    """One robot's place at the barrier."""

    live: bool = False
    last_act_tick: int = -1
    frames_owed: int = 0
    owes_from_tick: int = 0

    def owes(self, tick: int) -> bool:
        if not self.live or self.owes_from_tick > tick:
            return False
        return self.last_act_tick < tick or self.frames_owed > 0


class LockstepBarrier:
    """Who the world still waits for at each tick (the table in the module docstring)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.seats = {name: Seat() for name in self.names}
        self.tick = 0
        self.excused = dict.fromkeys(self.names, 0)
        """How many ticks went on without each robot's answer (`excuse`)."""

    def join(self, name: str) -> None:
        self.seats[name] = Seat(live=True, owes_from_tick=self.tick + 1)

    def leave(self, name: str) -> None:
        self.seats[name] = Seat(live=False, owes_from_tick=self.tick + 1)

    def start(self) -> None:
        """Time starts at the current tick: robots already live owe it."""
        for seat in self.seats.values():
            seat.owes_from_tick = min(seat.owes_from_tick, self.tick)

    def act(self, name: str, tick: int, radio_frames: int) -> None:
        seat = self.seats[name]
        seat.frames_owed += radio_frames
        seat.last_act_tick = tick

    def frame(self, name: str) -> None:
        self.seats[name].frames_owed -= 1

    def excuse(self, name: str) -> None:
        """The current tick goes on without `name`'s answer; it stays live and is waited for
        again from the next tick (module docstring, "Lost messages")."""
        seat = self.seats[name]
        seat.owes_from_tick = self.tick + 1
        seat.frames_owed = 0
        self.excused[name] += 1

    def live(self) -> frozenset[str]:
        return frozenset(n for n, s in self.seats.items() if s.live)

    def waiting(self) -> frozenset[str]:
        """The live robots the current tick still waits for."""
        return frozenset(n for n, s in self.seats.items() if s.owes(self.tick))

    def complete(self) -> bool:
        return not self.waiting()

    def owed(self) -> tuple[int, int]:
        """What the current tick still waits for: acts of live robots, and the frames that
        robots which have answered announced and that have not come (the world wakes when as
        many have arrived, not at every message)."""
        acts = frames = 0
        for seat in self.seats.values():
            if not seat.owes(self.tick):
                continue
            if seat.last_act_tick < self.tick:
                acts += 1
            else:
                frames += max(seat.frames_owed, 0)
        return acts, frames

    def advance(self) -> int:
        """The current tick is done (whether or not it was complete): on to the next."""
        self.tick += 1
        return self.tick

    def export_state(self) -> dict[str, object]:
        """The tick and every seat, as JSON-able values (for a world checkpoint)."""
        return {
            "tick": self.tick,
            "seats": {
                name: {
                    "live": s.live,
                    "last_act_tick": s.last_act_tick,
                    "frames_owed": s.frames_owed,
                    "owes_from_tick": s.owes_from_tick,
                }
                for name, s in self.seats.items()
            },
            "excused": dict(self.excused),
        }

    def resume(self, state: Mapping[str, object]) -> None:
        """Carry on at the exported tick, in a restarted world.

        Every seat comes back not live: which robots are alive now is the liveliness tokens'
        to say (each `join` gives a clean seat), and a robot that died meanwhile must not be
        waited for.  Frames announced to the dead world are lost with it, so none are owed."""
        tick = state["tick"]
        if not isinstance(tick, int) or tick < 0:
            raise ValueError(f"lockstep tick {tick!r} is not a tick")
        self.tick = tick
        self.seats = {name: Seat(live=False, owes_from_tick=tick) for name in self.names}
        excused = state.get("excused", {})  # absent from checkpoints of older worlds
        if isinstance(excused, Mapping):
            for name in self.names:
                count = excused.get(name, 0)
                self.excused[name] = count if isinstance(count, int) and count >= 0 else 0


class LockstepPacer:
    """Holds lockstep ticks back so simulated time runs at most `max_speed` times the wall clock.

    A run that falls behind (slow robots) carries on from where it is at the same pace; it does
    not run faster to catch up. `wait_until` is called with a timeout in seconds and returns
    early (True) when the run is being stopped."""

    def __init__(
        self,
        max_speed: float | None,
        wait_until: Callable[[float], bool],
        clock_s: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_speed = max_speed
        self._wait = wait_until
        self._clock_s = clock_s
        self._start_s: float | None = None

    def before_tick(self, sim_t_ns: int) -> None:
        """Wait until the tick that starts at `sim_t_ns` is due (the first one starts the clock)."""
        if self.max_speed is None:
            return
        now_s = self._clock_s()
        wall_offset_s = sim_t_ns / NS_PER_S / self.max_speed
        due_s = now_s if self._start_s is None else self._start_s + wall_offset_s
        if due_s > now_s:
            self._wait(due_s - now_s)
        else:  # behind (or the first tick): start the pace from here, never catch up faster
            self._start_s = now_s - wall_offset_s


@dataclass
class LockstepProfile:
    """Wall time per lockstep phase and per robot's answer, summed since time started."""

    ticks: int = 0
    phase_ns: dict[str, int] = field(default_factory=lambda: dict.fromkeys(TICK_PHASES, 0))
    answer_ns: dict[str, list[int]] = field(default_factory=dict)
    """Per robot: sense message out -> its act in, the most recent `ANSWERS_KEPT`."""

    ANSWERS_KEPT = 2000

    def tick_done(self, phase_ends_ns: Sequence[int]) -> None:
        """One tick: its start, then the end of each of `TICK_PHASES` (monotonic ns)."""
        if len(phase_ends_ns) != len(TICK_PHASES) + 1:
            raise ValueError(f"{len(phase_ends_ns)} instants for {len(TICK_PHASES)} phases")
        self.ticks += 1
        for phase, start, end in zip(
            TICK_PHASES, phase_ends_ns[:-1], phase_ends_ns[1:], strict=True
        ):
            self.phase_ns[phase] += end - start

    def answered(self, robot: str, took_ns: int) -> None:
        kept = self.answer_ns.setdefault(robot, [])
        kept.append(took_ns)
        if len(kept) > 2 * self.ANSWERS_KEPT:
            del kept[: -self.ANSWERS_KEPT]

    def phase_ms_per_tick(self) -> dict[str, float]:
        """Mean wall milliseconds per tick in each phase (0 before the first tick)."""
        ticks = max(self.ticks, 1)
        return {phase: round(ns / ticks / 1e6, 4) for phase, ns in self.phase_ns.items()}

    def answer_p50_ms(self) -> dict[str, float]:
        """Per robot: median of sense out -> act in over the recent ticks, in ms."""
        out = {}
        for robot, kept in self.answer_ns.items():
            recent = sorted(kept[-self.ANSWERS_KEPT :])
            out[robot] = round(recent[len(recent) // 2] / 1e6, 4)
        return out

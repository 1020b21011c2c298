"""How many messages a robot may put on one of its keys: the world's guard against a robot that
floods them.

The router lets robotN put on its own act, radio and telemetry keys (services/router/access.py)
and bounds each message's size, not how many come.  A robot puts at most one act message and
one radio frame per control tick, and telemetry at its own lower rate, so a robot putting
thousands a second is broken or hostile.  Without a bound the world took every one.  A robot
that flooded signed radio frames in its own name for 10 s made the world queue them and relay
each to every other robot (they are valid).  The world's clock ran at 0.08-0.10 of real time
during the flood and at 0.0-0.3 for the 10 s after it, and the world grew by 200 MiB
(docs/robustness.md, "A robot that floods its keys").

`InputBudget` is a token bucket per robot: each control period gives a robot `per_period`
messages, up to `burst` saved, where a period is counted on whichever clock ran further since
its last message, the simulated one or the wall clock.  In lockstep a robot answers once per
tick of simulated time, however fast the lockstep runs; in real time a robot in a safe stop
(no sense message for a while, the world starved or gone) still acts and reports once per wall
period while the world's simulated time stands still.  Twice what a robot can use per period,
so a robot whose messages come in a clump (a late tick, a busy host: `BURST`) still has them
all taken, and one that had its budget used up by someone else gets it back.  What
is over the budget is dropped where it arrives, in the subscriber's callback, before it is
queued, and counted per robot.  A pure state machine: no Zenoh, no threads, the time only as an
argument.
"""

from __future__ import annotations

from collections.abc import Sequence

PER_PERIOD = 2
"""Messages a robot may put per control period on one key."""
BURST = 200
"""How many of them it may save up: a hundred periods' worth.  The budget is checked when the
world's callback runs, not when the message came, so a callback held up by a busy host (its
thread waiting for a core or for the interpreter) finds every message of the hold in one clump
with the time of the end of the hold: a second of a robot's acts must still be taken then."""


class InputBudget:
    """One key's budget for each robot (module docstring)."""

    def __init__(
        self,
        robots: Sequence[str],
        period_ns: int,
        per_period: int = PER_PERIOD,
        burst: int = BURST,
    ) -> None:
        if period_ns <= 0 or per_period <= 0 or burst < per_period:
            raise ValueError(
                f"a budget needs a positive period and rate and a burst of at least the rate: "
                f"{period_ns} ns, {per_period}, {burst}"
            )
        self._cost_ns = period_ns // per_period
        """Simulated time that earns one message."""
        self._capacity_ns = burst * self._cost_ns
        self._credit_ns = dict.fromkeys(robots, self._capacity_ns)
        self._at: dict[str, tuple[int, int] | None] = dict.fromkeys(robots, None)
        """Per robot: (simulated, wall) time of its last message."""
        self.refused = dict.fromkeys(robots, 0)
        """Messages dropped per robot since the start."""

    def take(self, robot: str, sim_ns: int, wall_ns: int) -> bool:
        """Whether a message of `robot` that arrived at simulated time `sim_ns` and monotonic
        wall time `wall_ns` is taken (True for a name outside the swarm: the caller counts
        those itself)."""
        credit_ns = self._credit_ns.get(robot)
        if credit_ns is None:
            return True
        at = self._at[robot]
        if at is None:
            self._at[robot] = (sim_ns, wall_ns)
        else:
            earned_ns = max(sim_ns - at[0], wall_ns - at[1])
            if earned_ns > 0:
                credit_ns = min(self._capacity_ns, credit_ns + earned_ns)
            self._at[robot] = (max(at[0], sim_ns), max(at[1], wall_ns))
        if credit_ns < self._cost_ns:
            self._credit_ns[robot] = credit_ns
            self.refused[robot] += 1
            return False
        self._credit_ns[robot] = credit_ns - self._cost_ns
        return True

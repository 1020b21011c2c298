"""Whether a real-time run held real time: the world kept up and every robot kept its control
deadlines.  One criterion for `bench/scale.py` (the largest swarm a host holds, docs/scale.md)
and for the report `swarm up` prints at the end of a run; no heavy import, so the command line
stays quick."""

from __future__ import annotations

from collections.abc import Mapping

HOLD_MISS_SHARE = 0.01
"""A real-time run holds when no robot misses more than this share of its control deadlines
..."""
HOLD_REAL_TIME_FACTOR = 0.99
"""... and the world keeps up: at least this many simulated seconds per wall second."""


def holds_real_time(real_time_factor: float | None, worst_miss_share: float | None) -> bool:
    """Whether a real-time run held: the world kept up and every robot kept its deadlines."""
    return (
        real_time_factor is not None
        and real_time_factor >= HOLD_REAL_TIME_FACTOR
        and worst_miss_share is not None
        and worst_miss_share <= HOLD_MISS_SHARE
    )


def real_time_shortfalls(
    real_time_factor: float | None, deadlines: Mapping[str, tuple[int, int]]
) -> list[str]:
    """Why a real-time run did not hold (`holds_real_time`), in words: the world's pace and the
    robots that missed too many deadlines, from (missed, ticks) per robot; empty when it held
    or when nothing was measured."""
    shortfalls: list[str] = []
    if real_time_factor is not None and real_time_factor < HOLD_REAL_TIME_FACTOR:
        shortfalls.append(
            f"the world ran at {real_time_factor:.2f} of real time (at least "
            f"{HOLD_REAL_TIME_FACTOR} holds)"
        )
    shares = {name: missed / ticks for name, (missed, ticks) in deadlines.items() if ticks > 0}
    late = [name for name, share in shares.items() if share > HOLD_MISS_SHARE]
    if late:
        worst = max(late, key=lambda name: shares[name])
        shortfalls.append(
            f"{len(late)} of {len(shares)} robots missed more than "
            f"{100 * HOLD_MISS_SHARE:.0f} % of their control deadlines (worst {worst}: "
            f"{100 * shares[worst]:.1f} %)"
        )
    return shortfalls

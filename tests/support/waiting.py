"""Polling a condition until it holds: the one `wait_for` of the test harnesses.

Time enters through `clock` and `sleep` (monotonic seconds by default), so a test can drive the
loop with a fake clock and no real waiting.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

_MAX_REPR_CHARS = 1000


def describe_predicate(predicate: Callable[[], object]) -> str:
    """A name for a condition: a function's qualified name, a lambda's source line."""
    name = getattr(predicate, "__qualname__", None) or repr(predicate)
    if not name.endswith("<lambda>"):
        return name
    try:
        lines, _ = inspect.getsourcelines(predicate)
    except (OSError, TypeError):
        return name
    return " ".join(line.strip() for line in lines)[:200]


def wait_for(
    predicate: Callable[[], T | None],
    timeout_s: float = 90.0,
    every_s: float = 0.5,
    describe: str | None = None,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> T:
    """Call `predicate` every `every_s` until it returns a truthy value, and return that value.

    A predicate may return None or any falsy value for "not yet" (so `T | None` types it).

    The predicate runs at least once, and once more when the time-out has passed. An exception it
    raises propagates. On time-out: AssertionError naming the condition (`describe`, else the
    predicate's name or source line), the time-out and the last value returned.
    """
    if timeout_s < 0 or every_s <= 0:
        raise ValueError(
            f"wait_for needs timeout_s >= 0 and every_s > 0, not {timeout_s}, {every_s}"
        )
    deadline_s = clock() + timeout_s
    while True:
        last = predicate()
        if last:
            return last
        left_s = deadline_s - clock()
        if left_s <= 0:
            break
        sleep(min(every_s, left_s))
    last_repr = repr(last)
    if len(last_repr) > _MAX_REPR_CHARS:
        last_repr = last_repr[:_MAX_REPR_CHARS] + "..."
    what = describe if describe is not None else describe_predicate(predicate)
    raise AssertionError(f"{what}: not met within {timeout_s:g} s; last value {last_repr}")

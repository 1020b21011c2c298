"""A monotonic clock that moves only when something sleeps on it: loops with no real waiting."""

from __future__ import annotations


class FakeClock:
    def __init__(self, now_s: float = 100.0) -> None:
        self.now_s = now_s
        self.sleeps_s: list[float] = []

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, duration_s: float) -> None:
        assert duration_s >= 0, duration_s
        self.sleeps_s.append(duration_s)
        self.now_s += duration_s

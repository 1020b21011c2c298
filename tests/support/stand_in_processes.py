"""Child processes the launcher can supervise without starting anything: a process factory for
`services.launcher.launcher.Launcher(plan, factory=...)` whose children only record signals."""

from __future__ import annotations

import itertools
import signal
from collections.abc import Iterator
from dataclasses import dataclass, field


@dataclass
class StandInProcess:
    """What the launcher sees of a child: a pid, and whether it still runs."""

    pid: int
    returncode: int | None = None
    signals: list[int] = field(default_factory=list)
    """Every signal sent with `send_signal`, in order."""
    ended: list[int] | None = None
    """Where the pid is appended when a signal ends it (the factory's `ended`, shared)."""

    def poll(self) -> int | None:
        return self.returncode

    def kill(self) -> None:
        self.returncode = -9

    def send_signal(self, sig: int) -> None:
        """SIGSTOP and SIGCONT leave it running, as they leave a real process; any other
        signal ends it."""
        self.signals.append(sig)
        if sig not in (signal.SIGSTOP, signal.SIGCONT):
            self.returncode = -sig
            if self.ended is not None:
                self.ended.append(self.pid)

    def wait(self, timeout: float | None = None) -> int | None:
        return self.returncode


@dataclass
class StandInFactory:
    """Makes a `StandInProcess` per start; `started` lists them in order."""

    pids: Iterator[int] = field(default_factory=lambda: itertools.count(1000))
    started: list[StandInProcess] = field(default_factory=list)
    ended: list[int] = field(default_factory=list)
    """The pids of the children a signal ended, in the order they ended."""

    def __call__(self, _argv: list[str], _log: object, _env: dict[str, str]) -> StandInProcess:
        child = StandInProcess(next(self.pids), ended=self.ended)
        self.started.append(child)
        return child

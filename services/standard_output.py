"""A command's standard output on a device that refuses writes (a full disk, a quota, an I/O
error): the command goes on, without it.

`swarm status > status.json` on a full disk, or `swarm up > run.txt` whose disk fills, used to
end in a traceback at the first `print`; `swarm up` took the whole swarm down with it, right
after starting it.  `guard_standard_output` puts a `GuardedOutput` in front of `sys.stdout` for
a command's own process: the first refused write is reported once on stderr, the rest of the
output is dropped (file descriptor 1 then points at /dev/null, so that no later flush, Python's
own at exit included, fails again), and `lost` tells the command's exit status.  A reader gone
away (`| head`, EPIPE) is not this case: the command's own BrokenPipeError handling stays.
"""

from __future__ import annotations

import errno
import os
import sys
from typing import TextIO

REFUSED_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO})
"""What a device full or failing answers a write; anything else is raised as before."""


class GuardedOutput:
    """`inner` (a text stream) whose writes that the device refuses are dropped, once said so
    on stderr as `command`.  Every other attribute is `inner`'s."""

    def __init__(self, inner: TextIO, command: str) -> None:
        self._inner = inner
        self._command = command
        self.lost: OSError | None = None
        """The first refused write, None while every write went through."""

    def write(self, text: str) -> int:
        if self.lost is None:
            try:
                return self._inner.write(text)
            except OSError as exc:
                self._refused(exc)
        return len(text)

    def writelines(self, lines: list[str]) -> None:
        for line in lines:
            self.write(line)

    def flush(self) -> None:
        if self.lost is None:
            try:
                self._inner.flush()
            except OSError as exc:
                self._refused(exc)

    def __getattr__(self, name: str) -> object:
        return getattr(self._inner, name)

    def _refused(self, exc: OSError) -> None:
        if exc.errno not in REFUSED_WRITE_ERRNOS:
            raise exc
        self.lost = exc
        try:  # what the inner stream still buffers goes nowhere, without another error
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, self._inner.fileno())
            finally:
                os.close(devnull)
        except (OSError, ValueError):
            pass  # no descriptor to redirect: the buffer's flush at exit may complain once
        print(
            f"swarm {self._command}: cannot write to standard output ({exc.strerror}); the "
            "rest of this command's output is dropped",
            file=sys.stderr,
            flush=True,
        )


def guard_standard_output(command: str) -> GuardedOutput | None:
    """Put a `GuardedOutput` in front of this process's stdout (None when it has none)."""
    if sys.stdout is None or isinstance(sys.stdout, GuardedOutput):
        return sys.stdout
    guarded = GuardedOutput(sys.stdout, command)
    sys.stdout = guarded
    return guarded

"""No swarm outlives its launcher: a child of `swarm up` ends when the launcher does.

The launcher starts every child in a session of its own (so a Ctrl-C in the terminal reaches the
launcher alone, which stops the children in order).  A launcher that dies without that orderly
stop (`kill -9`, the out-of-memory killer, a crash) used to leave the router, the world and the
robots running unsupervised, holding the run's port, so the next `swarm up` on it failed.  Each
child started by a launcher (`LAUNCHER_PID_ENV` set) now asks the kernel, as it starts, for
SIGTERM when its parent ends (Linux `prctl(PR_SET_PDEATHSIG)`), and ends at once if the
launcher has already gone.  SIGTERM is the same orderly stop the launcher sends: the world
writes its final summary first.  Elsewhere than Linux nothing changes.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys

LAUNCHER_PID_ENV = "SWARM_LAUNCHER_PID"
"""Set by the launcher in every child's environment: its own process id."""
_PR_SET_PDEATHSIG = 1

log = logging.getLogger("swarm.launcher")


def end_with_the_launcher() -> None:
    """In a process the launcher started: SIGTERM to this process when the launcher ends (and
    now, if it already has).  Nothing for a process started otherwise, or off Linux."""
    launcher_pid = os.environ.get(LAUNCHER_PID_ENV)
    if not launcher_pid or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        log.warning(
            "cannot ask to end with the launcher (%s): this process outlives it",
            os.strerror(ctypes.get_errno()),
        )
        return
    if str(os.getppid()) != launcher_pid:  # it ended before the request was in place
        log.warning(
            "$%s names launcher %s, and this process's parent is %d: that launcher has "
            "ended, so this process ends too (unset %s to run a command on its own)",
            LAUNCHER_PID_ENV,
            launcher_pid,
            os.getppid(),
            LAUNCHER_PID_ENV,
        )
        os.kill(os.getpid(), signal.SIGTERM)


def end_with_its_parent() -> None:
    """A `preexec_fn` for a child this process starts (between fork and exec): SIGTERM to the
    child when this process ends, however it ends (Linux; nothing elsewhere).  `swarm replay`
    gives it to Rerun's server, which a killed replay used to leave serving, holding its
    ports."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)

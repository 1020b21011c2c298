"""One `swarm up` per run directory: an exclusive lock held while the launcher runs.

A second `swarm up` on the directory of a live run (the default `runs/swarm`, typed again in
another terminal) used to write fresh credentials over the live run's before failing on its
taken port: `swarm status` then logged in with a password the live router did not know, and a
robot the live launcher restarted could not log in at all.  It also truncated the live run's
router log.  Now the launcher takes `<dir>/.swarm-up.lock` with `flock` before it writes
anything and keeps it until it ends; a second launcher finds it taken and stops with a message
naming the first one's process id.  The kernel drops the lock when its holder's process ends,
however it ends, so a killed launcher leaves nothing stale behind; the file itself stays.

`swarm dashboard --out DIR` takes its own lock in the same way (`DASHBOARD_LOCK_FILE_NAME`, so
the dashboard that `swarm up` starts in its run directory is not refused by its launcher's
lock): a second dashboard recording into the same folder used to move the live recording
aside as if it were an old one, cut what looked like its half-written end while it was being
written, and leave the run's recording under another name.  `swarm tune --out DIR` too
(`TUNE_LOCK_FILE_NAME`): two tuners in one folder wrote each other's checkpoints and results.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from swarm_config.atomic_files import FileWriteError

LOCK_FILE_NAME = ".swarm-up.lock"
DASHBOARD_LOCK_FILE_NAME = ".swarm-dashboard.lock"
TUNE_LOCK_FILE_NAME = ".swarm-tune.lock"


class RunDirectoryBusyError(ValueError):
    """Another live `swarm up` holds the directory; the message says which and what to do."""


class RunDirectoryLock:
    """The exclusive lock of one directory, held from `acquire` until `release`."""

    def __init__(self, descriptor: int) -> None:
        self._descriptor: int | None = descriptor

    @classmethod
    def acquire(
        cls,
        directory: Path,
        what: str,
        instead: str,
        command: str = "swarm up",
        lock_file_name: str = LOCK_FILE_NAME,
    ) -> RunDirectoryLock:
        """Lock `directory` (made if missing) for this process; RunDirectoryBusyError when another
        process holds it.  `what` names the directory's role in the message (e.g. "run
        directory"), `instead` how to give this run another one (e.g. "--out DIR"); `command`
        is what holds such locks, each kind in its own `lock_file_name`."""
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / lock_file_name
        try:
            descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        except OSError as exc:  # a folder in its place, a read-only file system
            raise FileWriteError(exc.errno, exc.strerror or str(exc), str(path)) from None
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _pid_text(os.read(descriptor, 32)) or "unknown"
            os.close(descriptor)
            raise RunDirectoryBusyError(
                f"{directory} is the {what} of another `{command}` that is still running "
                f"(pid {holder}): stop that one first (Ctrl-C in its terminal), or give this "
                f"one another ({instead})"
            ) from None
        try:
            os.ftruncate(descriptor, 0)
            os.write(descriptor, f"{os.getpid()}\n".encode("ascii"))
        except OSError as exc:  # a full disk or quota: the pid does not fit
            os.close(descriptor)
            raise FileWriteError(exc.errno, exc.strerror or str(exc), str(path)) from None
        return cls(descriptor)

    def release(self) -> None:
        """Let the directory go (again: nothing)."""
        if self._descriptor is not None:
            os.close(self._descriptor)  # closing the file drops its flock
            self._descriptor = None


def _pid_text(written: bytes) -> str:
    return written.decode("ascii", "replace").strip()


def recorded_holder(directory: Path, lock_file_name: str = LOCK_FILE_NAME) -> int | None:
    """The process id the last holder of `directory`'s lock wrote in it, None without one.
    Read without taking the lock (a test of it could refuse a launcher starting that moment):
    the process may have ended since, and its id gone to another."""
    try:
        return int(_pid_text((directory / lock_file_name).read_bytes()[:32]))
    except (OSError, ValueError):
        return None

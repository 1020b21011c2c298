"""One `swarm up` per run directory (services/launcher/run_lock.py), with a real second process
holding the lock: refused while it lives, free again the moment it is killed."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from services.launcher.run_lock import LOCK_FILE_NAME, RunDirectoryBusyError, RunDirectoryLock
from tests.integration.conftest import ROOT

HOLD = """
import sys, time
from pathlib import Path
from services.launcher.run_lock import RunDirectoryLock
RunDirectoryLock.acquire(Path(sys.argv[1]), "run directory", "--out DIR")
print("held", flush=True)
time.sleep(600)
"""


def test_a_directory_held_by_a_live_process_is_refused_and_freed_when_it_is_killed(
    tmp_path: Path,
) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(tmp_path)], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(RunDirectoryBusyError) as refused:
            RunDirectoryLock.acquire(tmp_path, "run directory", "--out DIR")
        assert f"still running (pid {holder.pid})" in str(refused.value)
        assert "another (--out DIR)" in str(refused.value)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
        if holder.stdout is not None:
            holder.stdout.close()
    # A killed holder leaves the file but not the lock.
    assert (tmp_path / LOCK_FILE_NAME).exists()
    lock = RunDirectoryLock.acquire(tmp_path, "run directory", "--out DIR")
    lock.release()
    lock.release()  # again: nothing


def test_a_released_lock_can_be_taken_again_and_makes_a_missing_directory(
    tmp_path: Path,
) -> None:
    directory = tmp_path / "new" / "run"
    first = RunDirectoryLock.acquire(directory, "run directory", "--out DIR")
    with pytest.raises(RunDirectoryBusyError):
        RunDirectoryLock.acquire(directory, "run directory", "--out DIR")
    first.release()
    RunDirectoryLock.acquire(directory, "run directory", "--out DIR").release()

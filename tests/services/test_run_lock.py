"""One `swarm up` per run directory (services/launcher/run_lock.py), with a real second process
holding the lock: refused while it lives, free again the moment it is killed; and `swarm
credentials` leaves a credentials directory that a live run holds alone."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from services.launcher.run_lock import (
    DASHBOARD_LOCK_FILE_NAME,
    LOCK_FILE_NAME,
    RunDirectoryBusyError,
    RunDirectoryLock,
)
from tests.integration.conftest import ROOT

HOLD = """
import sys, time
from pathlib import Path
from services.launcher.run_lock import RunDirectoryLock
RunDirectoryLock.acquire(Path(sys.argv[1]), "run directory", "--out DIR")
print("held", flush=True)
time.sleep(600)
"""


def _hold(directory: Path) -> subprocess.Popen[str]:
    """A second process that holds `directory`'s lock until it is killed."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(directory)], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    return holder


def _end(holder: subprocess.Popen[str]) -> None:
    holder.send_signal(signal.SIGKILL)
    holder.wait(timeout=30)
    if holder.stdout is not None:
        holder.stdout.close()


def test_a_directory_held_by_a_live_process_is_refused_and_freed_when_it_is_killed(
    tmp_path: Path,
) -> None:
    holder = _hold(tmp_path)
    try:
        with pytest.raises(RunDirectoryBusyError) as refused:
            RunDirectoryLock.acquire(tmp_path, "run directory", "--out DIR")
        assert f"still running (pid {holder.pid})" in str(refused.value)
        assert "another (--out DIR)" in str(refused.value)
    finally:
        _end(holder)
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


def test_a_dashboards_lock_and_a_launchers_lock_of_one_folder_are_apart(tmp_path: Path) -> None:
    # `swarm up` holds its run directory and starts a dashboard that records into it.
    launcher = RunDirectoryLock.acquire(tmp_path, "run directory", "--out DIR")
    dashboard = RunDirectoryLock.acquire(
        tmp_path, "recording folder", "--out DIR", "swarm dashboard", DASHBOARD_LOCK_FILE_NAME
    )
    with pytest.raises(RunDirectoryBusyError, match="of another `swarm dashboard` that is"):
        RunDirectoryLock.acquire(
            tmp_path, "recording folder", "--out DIR", "swarm dashboard", DASHBOARD_LOCK_FILE_NAME
        )
    dashboard.release()
    launcher.release()


def _credential_files(directory: Path) -> dict[str, bytes]:
    """Every file of a credentials directory but the lock, by name."""
    return {
        p.name: p.read_bytes()
        for p in directory.iterdir()
        if p.is_file() and p.name != LOCK_FILE_NAME
    }


def test_swarm_credentials_leaves_a_directory_a_live_run_holds_alone(tmp_path: Path) -> None:
    cli = [sys.executable, "-m", "services.cli.main", "credentials", str(tmp_path)]
    made = subprocess.run(cli, capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert made.returncode == 0, made.stderr
    before = _credential_files(tmp_path)
    holder = _hold(tmp_path)
    try:
        for extra in ((), ("--rotate",)):
            refused = subprocess.run(
                [*cli, *extra], capture_output=True, text=True, cwd=ROOT, timeout=60
            )
            assert refused.returncode == 2, refused.stderr
            assert f"still running (pid {holder.pid})" in refused.stderr
            assert "Traceback" not in refused.stderr
            assert _credential_files(tmp_path) == before
    finally:
        _end(holder)
    again = subprocess.run([*cli, "--rotate"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert again.returncode == 0, again.stderr

"""A process named as a launcher's child whose launcher has gone ends, and says why
(services/launcher/orphans.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from services.launcher.orphans import LAUNCHER_PID_ENV

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_command_with_another_launchers_pid_in_its_environment_says_why_it_ends() -> None:
    """A robot's environment copied into a shell to run a command by hand carries the
    launcher's process id: every `swarm` command then ended at once with no word."""
    result = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "scenario", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, LAUNCHER_PID_ENV: "1"},
        timeout=60,
    )
    assert result.returncode == -signal.SIGTERM
    assert result.stdout == ""
    assert f"${LAUNCHER_PID_ENV} names launcher 1, and this process's parent is {os.getpid()}" in (
        result.stderr
    )
    assert f"unset {LAUNCHER_PID_ENV} to run a command on its own" in result.stderr

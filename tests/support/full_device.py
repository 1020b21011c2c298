"""A `swarm` command run with its standard output on /dev/full, whose every write fails with
ENOSPC: what a full disk does to `swarm ... > file` (services/standard_output.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

DEV_FULL = Path("/dev/full")


def run_with_stdout_on_a_full_device(
    args: list[str], cwd: Path, timeout_s: float = 600.0
) -> subprocess.CompletedProcess[str]:
    """`python -m services.cli.main ARGS` with stdout on /dev/full and stderr captured."""
    with DEV_FULL.open("w") as full:
        return subprocess.run(
            [sys.executable, "-m", "services.cli.main", *args],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            cwd=cwd,
            timeout=timeout_s,
        )

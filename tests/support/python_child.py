"""Run a snippet of Python in a child interpreter of this environment, from the repository's
root, with extra environment variables (a process of another kind: SWARM_KERNELS,
SWARM_NATIVE)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def run_python(
    code: str, env: dict[str, str], stdin: bytes = b"", timeout_s: float = 900.0
) -> subprocess.CompletedProcess[bytes]:
    """`python -c code` with `env` added to this process's environment; never raises on the
    child's exit status (the caller asserts on it)."""
    return subprocess.run(
        [sys.executable, "-c", code],
        input=stdin,
        capture_output=True,
        env={**os.environ, **env},
        cwd=ROOT,
        timeout=timeout_s,
        check=False,
    )

"""Replaying a recorded run: serve a `.rrd` file to the web viewer.

The Rerun command line that ships with rerun-sdk does the serving (`rerun --serve-web FILE.rrd
--port GRPC --web-viewer-port WEB`): it loads the file, recording and blueprint, into a gRPC
server and hosts the web viewer next to it. This module starts its binary (the one bundled in
the `rerun_cli` package, not the `rerun` script, which would leave the binary behind when
stopped) as a child process and stops it on SIGTERM or Ctrl-C. `rerun FILE.rrd` opens the
same file in the native viewer on a machine with a display.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
import threading
from pathlib import Path

from services.launcher.orphans import end_with_its_parent

MIN_SERVER_MEMORY_MIB = 256


def server_memory_limit_for(recording: Path) -> str:
    """Room for the whole file several times over, so a late viewer still gets all of it."""
    size_mib = recording.stat().st_size / 2**20
    return f"{max(MIN_SERVER_MEMORY_MIB, math.ceil(4 * size_mib))}MiB"


def rerun_executable() -> Path:
    """The Rerun binary bundled with rerun-sdk ($RERUN_CLI_PATH overrides it)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return Path(override)
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the rerun_cli package of rerun-sdk is not installed")
    package = Path(next(iter(spec.submodule_search_locations)))
    if sys.platform == "darwin" and (package / "Rerun.app").exists():
        return package / "Rerun.app" / "Contents" / "MacOS" / "Rerun"
    return package / ("rerun.exe" if sys.platform.startswith("win") else "rerun")


def replay_command(
    recording: Path, web_port: int, grpc_port: int, server_memory_limit: str, bind: str
) -> list[str]:
    """Rerun's server for `recording`, its web viewer and data server listening on `bind`."""
    return [
        str(rerun_executable()),
        "--serve-web",
        str(recording),
        "--bind",
        bind,
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
        "--server-memory-limit",
        server_memory_limit,
    ]


def serve_recording(command: list[str], stop: threading.Event, stop_timeout_s: float = 10.0) -> int:
    """Run the server until it exits or `stop` is set; its exit status, 0 after a stop."""
    process = subprocess.Popen(command, stdin=subprocess.DEVNULL, preexec_fn=end_with_its_parent)
    try:
        while process.poll() is None and not stop.wait(0.2):
            pass
    finally:
        if process.poll() is None:
            process.terminate()
            try:
                process.wait(timeout=stop_timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    return 0 if stop.is_set() else process.returncode

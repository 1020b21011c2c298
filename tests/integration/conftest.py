"""Real processes on loopback: a router, the world and one process per robot."""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TypeVar

import pytest

from tests.support.waiting import wait_for

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
T = TypeVar("T")


def free_port() -> int:
    return free_ports(1)[0]


def free_ports(count: int) -> list[int]:
    """`count` distinct free TCP ports on loopback (all held open until each is chosen)."""
    sockets = [socket.socket() for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [int(s.getsockname()[1]) for s in sockets]
    finally:
        for s in sockets:
            s.close()


def swarm_cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli.main", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
    )


def run_swarm(out: Path, *args: str, timeout: float = 600.0, port: int | None = None) -> dict:
    """`swarm up` to the end of its --duration (router on `port`, else a free one); returns
    the world's summary.json."""
    port = free_port() if port is None else port
    result = swarm_cli(
        "up", "--out", str(out), "--port", str(port), "--no-dashboard", *args, timeout=timeout
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads((out / "summary.json").read_text())


@dataclass
class LiveSwarm:
    process: subprocess.Popen[str]
    port: int
    out: Path

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return swarm_cli(*args, "--connect", self.endpoint, timeout=30)

    def admin(self, *args: str) -> dict:
        """The JSON reply of an admin command, or {} when nobody answered (yet)."""
        result = self.cli(*args)
        if not result.stdout:
            assert "no answer" in result.stderr or "no router at" in result.stderr, result.stderr
            return {}
        return json.loads(result.stdout)

    def all_running(self) -> dict:
        """The launcher's status once it has every process of the swarm running."""
        return self.wait_for(
            lambda: (
                (s := self.admin("status")).get("ok")
                and all(p["running"] for p in s["processes"].values())
                and s
            ),
            describe="every process running",
        )

    def wait_for(
        self,
        predicate: Callable[[], T | None],
        timeout_s: float = 90.0,
        every_s: float = 0.5,
        describe: str | None = None,
    ) -> T:
        return wait_for(predicate, timeout_s, every_s, describe)


def _pump_lines(stream: IO[str]) -> queue.SimpleQueue[str]:
    """Read `stream` line by line on a thread of its own until it ends ("" then): the output
    never fills its pipe, and the reader can wait for a line with a time-out."""
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()

    def pump() -> None:
        try:
            for line in stream:
                lines.put(line)
        except ValueError:  # the stream was closed under the reader
            pass
        lines.put("")

    threading.Thread(target=pump, name="swarm-up-output", daemon=True).start()
    return lines


@pytest.fixture
def live_swarm(
    tmp_path: Path, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> Iterator[LiveSwarm]:
    """A swarm started with `swarm up` (no duration), stopped with Ctrl-C at the end.

    The test talks to it as the operator: $SWARM_CREDENTIALS_FILE names the run's operator
    credentials for the test's own clients and the `swarm` commands it runs."""
    extra = getattr(request, "param", ())
    port = free_port()
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "up",
            "--no-dashboard",
            "--out",
            str(tmp_path),
            "--port",
            str(port),
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert process.stdout is not None
    output = _pump_lines(process.stdout)
    deadline = time.monotonic() + 60
    lines = []
    while (left_s := deadline - time.monotonic()) > 0:
        try:
            line = output.get(timeout=left_s)
        except queue.Empty:
            break
        lines.append(line)
        if line.startswith("swarm ") or not line:
            break
    if not any(line.startswith("swarm ") for line in lines):
        process.kill()
        process.wait()
        raise AssertionError(f"swarm up did not start within 60 s:\n{''.join(lines)}")
    monkeypatch.setenv("SWARM_CREDENTIALS_FILE", str(tmp_path / "credentials" / "operator.json"))
    swarm = LiveSwarm(process, port, tmp_path)
    try:
        yield swarm
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        process.stdout.close()

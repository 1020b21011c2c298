"""`swarm up` under a benchmark: start it on a free 127.0.0.1 port, ask its launcher and world
for their status (typed replies, with the run's operator credentials), stop it, and make sure
nothing it started outlives the benchmark; and `start_router`, a bare router with a run's
logins for benchmarks that play the other processes themselves.

Used by bench/swarm_runtime.py, bench/scale.py and bench/transport_floor.py.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Any

from proc_stats import alive, descendants

from robot_firmware.net.admin import admin_request
from robot_firmware.net.messages import LauncherStatusReply, WorldStatusReply
from services.router.access import router_config_document
from swarm_config.credentials import (
    ROUTER_USERS_FILE,
    ProcessCredentials,
    generate_credential_set,
    read_credentials,
    write_credential_set,
    write_private_file,
)

ROOT = Path(__file__).resolve().parents[1]
OPERATOR_CREDENTIALS = Path("credentials") / "operator.json"
"""Where `swarm up --out DIR` leaves the operator's credentials, inside DIR."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_router(
    credentials_dir: Path,
    swarm: str,
    robots: list[str],
    access_control: bool = True,
    log: IO[bytes] | int = subprocess.DEVNULL,
) -> tuple[str, dict[str, Path], subprocess.Popen[bytes]]:
    """`swarm router` on a free 127.0.0.1 port with fresh logins for `robots` and the services
    (written into `credentials_dir`) and, unless turned off, the run's access control: its
    endpoint, every identity's credentials file, and the process (the caller stops it)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    credentials = generate_credential_set(swarm, robots)
    files = write_credential_set(credentials_dir, credentials)
    document = router_config_document(credentials, credentials_dir / ROUTER_USERS_FILE, [endpoint])
    document["access_control"]["enabled"] = access_control
    router_config = credentials_dir / "router.json5"
    write_private_file(router_config, json.dumps(document).encode())
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "router",
            "--listen",
            endpoint,
            "--config",
            str(router_config),
        ],
        cwd=ROOT,
        stdout=log,
        stderr=log,
    )
    return endpoint, files, router


class SwarmUp:
    """One `swarm up --no-dashboard --out DIR --port PORT ...` child of this benchmark."""

    def __init__(self, out: Path, *args: str, swarm: str = "lab") -> None:
        self.out = out
        self.port = free_port()
        self.swarm = swarm
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        out.mkdir(parents=True, exist_ok=True)
        self._log = (out / "swarm-up.log").open("wb")
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.cli.main",
                "up",
                "--no-dashboard",
                "--out",
                str(out),
                "--port",
                str(self.port),
                "--swarm",
                swarm,
                *args,
            ],
            cwd=ROOT,
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )
        self._started: set[int] = set()
        self._operator: ProcessCredentials | None = None

    def operator_credentials(self, timeout_s: float = 60.0) -> ProcessCredentials:
        """The run's operator credentials, once swarm up has written them (before it starts
        the router): a client without them is refused by the router and keeps retrying."""
        if self._operator is None:
            path = self.out / OPERATOR_CREDENTIALS
            deadline = time.monotonic() + timeout_s
            while not path.exists():
                self._check_running()
                if time.monotonic() > deadline:
                    raise RuntimeError(f"swarm up wrote no {path} in {timeout_s:.0f} s")
                time.sleep(0.1)
            self._operator = read_credentials(path)
        return self._operator

    def _ask(self, target: str, reply_type: type[Any], timeout_s: float) -> Any:
        reply = admin_request(
            self.swarm, self.endpoint, target, "status", reply_type, None, timeout_s,
            self.operator_credentials(),
        )  # fmt: skip
        return reply if isinstance(reply, reply_type) else None

    def world_status(self, timeout_s: float = 2.0) -> WorldStatusReply | None:
        reply: WorldStatusReply | None = self._ask("world", WorldStatusReply, timeout_s)
        return reply

    def launcher_status(self, timeout_s: float = 2.0) -> LauncherStatusReply | None:
        reply: LauncherStatusReply | None = self._ask("launcher", LauncherStatusReply, timeout_s)
        if reply is not None:
            self._started.update(p.pid for p in reply.processes.values() if p.pid)
        return reply

    def pids(self) -> dict[str, int]:
        """Process name (router, world, robotN, ...) -> PID, with `launcher` for swarm up."""
        status = self.launcher_status()
        if status is None:
            raise RuntimeError(f"the launcher does not answer; see {self.out}/swarm-up.log")
        running = {name: p.pid for name, p in status.processes.items() if p.pid and p.running}
        return {"launcher": self.process.pid, **running}

    def wait_ticking(self, timeout_s: float = 60.0, ticks: int = 50) -> WorldStatusReply:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self._check_running()
            status = self.world_status()
            if status is not None and status.tick > ticks:
                return status
            time.sleep(0.5)
        raise RuntimeError(f"the swarm did not start in {timeout_s:.0f} s")

    def summary(self) -> dict[str, Any] | None:
        """DIR/summary.json as the world last wrote it (every few seconds, and at the end)."""
        try:
            data = json.loads((self.out / "summary.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def _check_running(self) -> None:
        if self.process.poll() is not None:
            raise RuntimeError(
                f"swarm up exited with status {self.process.returncode}; see {self.out}/logs"
            )

    def wait(self, timeout_s: float) -> int:
        """Wait for swarm up to end on its own (its --duration)."""
        return self.process.wait(timeout=timeout_s)

    def stop(self, timeout_s: float = 60.0) -> None:
        """Ctrl-C, as a user would stop it; then make sure every process it started is gone."""
        self._started.update(descendants(self.process.pid))
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)
        self.kill_leftovers()

    def kill_leftovers(self) -> None:
        """SIGKILL, by PID, every process this run started that still lives."""
        for pid in alive(self._started):
            try:
                Path(f"/proc/{pid}/cmdline").read_bytes().index(b"services.cli.main")
            except (OSError, ValueError):
                continue  # gone, or the PID now belongs to someone else
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self._log.close()

    def __enter__(self) -> SwarmUp:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

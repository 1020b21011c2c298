"""Real processes for the dashboard tests: a swarm (`swarm up`) and dashboards beside it."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import pyarrow as pa
import pytest

from swarm_config.credentials import generate_credential_set, write_credential_set

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Child:
    """A child process whose stdout and stderr go to a log file that the test can search."""

    name: str
    process: subprocess.Popen[bytes]
    log_path: Path
    log_file: IO[bytes]

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for_line(self, prefix: str, timeout_s: float = 60.0) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in self.output().splitlines():
                if line.startswith(prefix):
                    return line
            if self.process.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"{self.name}: no line starting {prefix!r}:\n{self.output()}")

    def stop(self, sig: signal.Signals = signal.SIGTERM, timeout_s: float = 30.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise AssertionError(
                f"{self.name} did not stop on {sig.name}:\n{self.output()}"
            ) from None
        finally:
            self.log_file.close()
        return code

    def shut_down(self) -> None:
        """Ctrl-C first, so that a launcher stops the processes it started; then SIGKILL."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log_file.close()


def start(name: str, argv: list[str], log_dir: Path) -> Child:
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"{name}.log"
    log_file = log_path.open("ab")
    process = subprocess.Popen(
        [sys.executable, *argv],
        stdout=log_file,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    return Child(name, process, log_path, log_file)


def swarm_credentials(base: Path, port: int) -> Path:
    """The credentials shared by dashboards started before the swarm on `port` and that swarm
    (`swarm up --credentials`): made by the first dashboard."""
    return base / f"credentials-{port}"


def start_swarm(out: Path, port: int, *extra: str) -> Child:
    argv = ["-m", "services.cli.main", "up", "--out", str(out), "--port", str(port)]
    shared = swarm_credentials(out.parent, port)
    if shared.exists():
        argv += ["--credentials", str(shared)]
    return start("swarm", [*argv, "--no-dashboard", *extra], out.parent / "logs")


@dataclass
class Dashboard:
    child: Child
    web_port: int
    grpc_port: int
    out: Path
    url: str = field(default="")


def start_dashboard(name: str, out: Path, router_port: int, log_dir: Path) -> Dashboard:
    web_port, grpc_port = free_port(), free_port()
    shared = swarm_credentials(log_dir.parent, router_port)
    if not shared.exists():
        write_credential_set(shared, generate_credential_set("lab", ("robot1", "robot2", "robot3")))
    argv = [
        "-m",
        "services.dashboard",
        "dashboard",
        "--credentials",
        str(shared / "dashboard.json"),
        "--scenario",
        str(PAPER),
        "--connect",
        f"tcp/127.0.0.1:{router_port}",
        "--out",
        str(out),
        "--web-port",
        str(web_port),
        "--grpc-port",
        str(grpc_port),
    ]
    dashboard = Dashboard(start(name, argv, log_dir), web_port, grpc_port, out)
    dashboard.url = dashboard.child.wait_for_line("open ").removeprefix("open ").strip()
    return dashboard


@dataclass
class EntityData:
    """What one entity of a recording holds: component columns and simulated times."""

    components: set[str] = field(default_factory=set)
    sim_times_s: list[float] = field(default_factory=list)
    rows: int = 0
    static: bool = False
    batches: list[pa.RecordBatch] = field(default_factory=list)

    def values(self, component: str) -> list[tuple[float, list[float]]]:
        """(sim time, value list) of every row that has `component`, in time order."""
        out: list[tuple[float, list[float]]] = []
        for batch in self.batches:
            if component not in batch.schema.names or "sim_time" not in batch.schema.names:
                continue
            times = batch.column("sim_time").cast(pa.int64()).to_pylist()
            for t_ns, value in zip(times, batch.column(component).to_pylist(), strict=True):
                if value is not None and t_ns is not None:
                    out.append((t_ns / 1e9, value))
        return sorted(out, key=lambda item: item[0])


def read_recording(path: Path) -> dict[str, EntityData]:
    """Every chunk of the file's recording, grouped by entity path."""
    from rerun.chunk import RrdReader

    entities: dict[str, EntityData] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        data = entities.setdefault(str(chunk.entity_path), EntityData())
        data.static = data.static or bool(chunk.is_static)
        data.rows += batch.num_rows
        data.batches.append(batch)
        data.components.update(n for n in batch.schema.names if ":" in n)
        if "sim_time" in batch.schema.names:
            times = batch.column("sim_time").cast(pa.int64()).to_pylist()
            data.sim_times_s.extend(t / 1e9 for t in times if t is not None)
    return entities


FINISHED_RECORDING_CHUNKS = 12


@pytest.fixture(scope="session")
def finished_recording(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A real recording stopped cleanly: one chunk per logged pose, then End with its footer."""
    import rerun as rr

    path = tmp_path_factory.mktemp("rrd") / "finished.rrd"
    recording = rr.RecordingStream("recording-file-test")
    recording.save(str(path))
    for i in range(FINISHED_RECORDING_CHUNKS):
        recording.set_time("sim_time", duration=i * 0.05)
        rr.log("/map/robots/robot1", rr.Points2D([[float(i), 2.0 * i]]), recording=recording)
        recording.flush(timeout_sec=5.0)
    recording.disconnect()
    return path.read_bytes()


def message_ends(data: bytes) -> list[int]:
    """Where each message of a recording ends, from its headers, up to and including End."""
    from services.dashboard.recording_file import END_KIND, MESSAGE_HEADER, STREAM_HEADER_BYTES

    ends, offset = [], STREAM_HEADER_BYTES
    while True:
        kind, length = MESSAGE_HEADER.unpack_from(data, offset)
        offset += MESSAGE_HEADER.size + length
        ends.append(offset)
        if kind == END_KIND:
            return ends


@pytest.fixture
def children() -> Iterator[list[Child]]:
    """Children a test starts; any still running at the end are killed."""
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.shut_down()

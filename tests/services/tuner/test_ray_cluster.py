"""`swarm tune --ray` on a real Ray cluster of two nodes on loopback, through the CLI.

The cluster is a head and one worker node, one CPU each, started with `ray start` as a user
would. A tune on it must give the best value and the convergence history of a local run, also
when the worker node's processes are killed while they evaluate a slice of a batch; a local
tune must never import Ray; a bad address is a one-line error that leaves no output folder.

Ray turns 127.0.0.1 into the machine's routable address, so the nodes take 127.0.0.2 and
127.0.0.3 (loopback too). Ray's servers listen on every interface whatever the node address,
so the cluster requires a random token (RAY_AUTH_MODE=token), known only to this test's
processes. `ray stop` would stop every Ray process of the machine, so the test stops its own:
the processes whose command line names its temporary folders, and their descendants.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from services.cli.main import main
from services.tuner.cluster import ClusterError, import_ray

ROOT = Path(__file__).resolve().parents[3]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
HEAD_IP = "127.0.0.2"
WORKER_IP = "127.0.0.3"
BUDGET = ["--algo", "ofa", "--budget", "120", "--duration", "2.0"]
"""Three generations of 40 candidates; a 20-candidate slice of 2 s takes about 0.45 s here."""
SLICE_TASK_TITLE = "ray::evaluate_candidate_slice"
"""What a Ray worker's command line reads while it runs a slice of a batch."""
START_TIMEOUT_S = 120.0
RUN_TIMEOUT_S = 150.0
FOLDER_FILES = ("convergence.csv", "best_fuzzy.yaml")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def process_table() -> dict[int, tuple[int, str, str]]:
    """pid -> (parent pid, start time in clock ticks, command line) of every process now, not
    counting zombies: a killed process stays one until its parent, or whatever inherits it,
    reaps it, which a container's first process may never do."""
    table: dict[int, tuple[int, str, str]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] == "Z":
            continue
        table[int(entry.name)] = (int(fields[1]), fields[19], command)
    return table


def processes_of(folder: Path) -> dict[int, str]:
    """pid -> start time of the processes naming ``folder`` and of all their descendants."""
    table = process_table()
    found = {pid for pid, (_, _, command) in table.items() if str(folder) in command}
    grown = True
    while grown:
        children = {pid for pid, (parent, _, _) in table.items() if parent in found} - found
        found |= children
        grown = bool(children)
    return {pid: table[pid][1] for pid in found}


def kill_processes(processes: dict[int, str]) -> None:
    """SIGKILL each process that still is the one recorded (same pid and start time)."""
    table = process_table()
    for pid, started in processes.items():
        if pid in table and table[pid][1] == started:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def alive(processes: dict[int, str]) -> list[int]:
    table = process_table()
    return [pid for pid, started in processes.items() if pid in table and table[pid][1] == started]


def stop_processes(processes: dict[int, str], grace_s: float = 2.0) -> None:
    """SIGTERM, then SIGKILL after ``grace_s`` (Ray's servers may ignore SIGTERM)."""
    for pid in alive(processes):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    while alive(processes) and time.monotonic() < deadline:
        time.sleep(0.1)
    kill_processes(processes)


@dataclass
class LocalCluster:
    address: str
    env: dict[str, str]
    head_dir: Path
    worker_dir: Path
    processes: dict[int, str]
    """Every process of both nodes seen so far (the final stop kills those still alive)."""

    def worker_processes(self) -> dict[int, str]:
        found = processes_of(self.worker_dir)
        self.processes.update(found)
        return found


def ray_command() -> list[str]:
    executable = Path(sys.executable).with_name("ray")
    return (
        [str(executable)] if executable.exists() else [sys.executable, "-m", "ray.scripts.scripts"]
    )


def ray_start(arguments: list[str], env: dict[str, str]) -> None:
    try:
        started = subprocess.run(
            [*ray_command(), "start", *arguments],
            env=env,
            capture_output=True,
            text=True,
            timeout=START_TIMEOUT_S,
            start_new_session=True,  # never in this test's process group
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"ray start {' '.join(arguments)} took more than {exc.timeout} s")
    if started.returncode != 0:
        pytest.fail(f"ray start {' '.join(arguments)} failed:\n{started.stdout}\n{started.stderr}")


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[LocalCluster]:
    probe = subprocess.run(
        [sys.executable, "-c", "import ray"], capture_output=True, text=True, timeout=120
    )
    if probe.returncode != 0:
        last_line = (probe.stderr.strip().splitlines() or ["no output"])[-1]
        pytest.skip(f"`import ray` fails ({last_line}); install the extra: pip install .[cluster]")
    head_dir = Path(tempfile.mkdtemp(prefix="ray-head-", dir="/tmp"))  # short: socket paths
    worker_dir = Path(tempfile.mkdtemp(prefix="ray-worker-", dir="/tmp"))
    port = free_port()
    env = {
        **os.environ,
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(16),
    }
    # The head marks a silent node dead after 3 missed 1 s health checks (Ray's default ~15 s).
    head_env = {
        **env,
        "RAY_health_check_period_ms": "1000",
        "RAY_health_check_timeout_ms": "1000",
        "RAY_health_check_failure_threshold": "3",
    }
    common = ["--num-cpus", "1", "--disable-usage-stats", "--object-store-memory", "100000000"]
    cluster = LocalCluster(f"{HEAD_IP}:{port}", env, head_dir, worker_dir, {})
    try:
        ray_start(
            ["--head", "--node-ip-address", HEAD_IP, "--port", str(port)]
            + ["--include-dashboard=false", f"--temp-dir={head_dir}", *common],
            head_env,
        )
        cluster.processes.update(processes_of(head_dir))
        ray_start(
            ["--address", cluster.address, "--node-ip-address", WORKER_IP]
            + [f"--temp-dir={worker_dir}", *common],
            env,
        )
        cluster.worker_processes()
        yield cluster
    finally:
        cluster.processes.update(processes_of(head_dir))
        cluster.processes.update(processes_of(worker_dir))
        stop_processes(cluster.processes)
        shutil.rmtree(head_dir, ignore_errors=True)
        shutil.rmtree(worker_dir, ignore_errors=True)


def tune_command(out: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "services.cli.main",
        "tune",
        "--scenario",
        str(PAPER),
        "--out",
        str(out),
        *BUDGET,
        *extra,
    ]


def run_outputs(out: Path) -> dict[str, str]:
    """What must be equal between two runs: history (Fig. 14 CSV) and best scheduler, as text."""
    outputs = {name: (out / "ofa" / name).read_text(encoding="utf-8") for name in FOLDER_FILES}
    outputs["best_fuzzy.yaml (all)"] = (out / "best_fuzzy.yaml").read_text(encoding="utf-8")
    return outputs


NO_RAY_PROBE = (
    "import sys\n"
    "from services.cli.main import main\n"
    "status = main(sys.argv[1:])\n"
    "print('ray in sys.modules:', 'ray' in sys.modules)\n"
    "sys.exit(status)\n"
)


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A local tune of the same budget, and its standard output."""
    out = tmp_path_factory.mktemp("local") / "tune"
    command = tune_command(out)
    finished = subprocess.run(
        [sys.executable, "-c", NO_RAY_PROBE, *command[3:]],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )
    assert finished.returncode == 0, finished.stderr
    return out, finished.stdout


def test_a_local_tune_never_imports_ray(local_run: tuple[Path, str]) -> None:
    _, stdout = local_run
    assert "ray in sys.modules: False" in stdout
    assert "Ray cluster" not in stdout


def test_a_tune_on_the_cluster_gives_the_local_best_and_history(
    ray_cluster: LocalCluster, local_run: tuple[Path, str], tmp_path: Path
) -> None:
    out = tmp_path / "tune"
    finished = subprocess.run(
        tune_command(out, "--ray", ray_cluster.address),
        cwd=ROOT,
        env=ray_cluster.env,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )
    assert finished.returncode == 0, finished.stderr
    print(finished.stdout)
    assert f"Ray cluster at {ray_cluster.address}, 2 CPUs on 2 nodes" in finished.stdout
    assert run_outputs(out) == run_outputs(local_run[0])
    assert "lost with its worker" not in finished.stderr


def test_a_worker_node_killed_mid_run_costs_only_its_slice(
    ray_cluster: LocalCluster, local_run: tuple[Path, str], tmp_path: Path
) -> None:
    out = tmp_path / "tune"
    stdout_path, stderr_path = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with stdout_path.open("w") as stdout, stderr_path.open("w") as stderr:
        tune = subprocess.Popen(
            tune_command(out, "--ray", ray_cluster.address),
            cwd=ROOT,
            env=ray_cluster.env,
            stdout=stdout,
            stderr=stderr,
        )
        try:
            killed = kill_worker_node_while_it_runs_a_slice(ray_cluster, tune)
            status = tune.wait(timeout=RUN_TIMEOUT_S)
        finally:
            if tune.poll() is None:
                tune.kill()
                tune.wait()
    output, errors = stdout_path.read_text(), stderr_path.read_text()
    print(output)
    print(errors)
    assert killed, "the worker node never ran a slice of a batch"
    assert status == 0, errors
    assert not alive(killed), "the worker node's processes survived SIGKILL"
    assert "lost with its worker" in errors and "submitted again" in errors
    assert run_outputs(out) == run_outputs(local_run[0])


def kill_worker_node_while_it_runs_a_slice(
    cluster: LocalCluster, tune: subprocess.Popen[bytes]
) -> dict[int, str]:
    """Wait until a worker of the worker node runs a slice, then SIGKILL every process of
    that node (raylet, workers, agents); return them, or {} if the tune ended first."""
    deadline = time.monotonic() + RUN_TIMEOUT_S
    while time.monotonic() < deadline and tune.poll() is None:
        table = process_table()
        node = cluster.worker_processes()
        if any(table[pid][2].startswith(SLICE_TASK_TITLE) for pid in node if pid in table):
            kill_processes(node)
            time.sleep(0.5)
            stragglers = cluster.worker_processes()  # a worker forked in the meantime
            kill_processes(stragglers)
            return {**node, **stragglers}
        time.sleep(0.005)
    return {}


def test_bad_cluster_addresses_are_one_line_errors_that_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    refused_port = free_port()
    with socket.socket() as silent:  # accepts connections and closes them: not a Ray GCS
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        closing = threading.Thread(target=lambda: silent.accept()[0].close(), daemon=True)
        closing.start()
        cases = {
            "127.0.0.1": "HOST:PORT",
            "127.0.0.1:http": "not a number",
            "127.0.0.1:70000": "1-65535",
            "ray://127.0.0.1:10001": "without a scheme",
            f"127.0.0.1:{refused_port}": "cannot reach a Ray cluster",
            f"127.0.0.1:{silent.getsockname()[1]}": "not as a Ray cluster's GCS",
        }
        for address, expected in cases.items():
            out = tmp_path / "tune"
            status = main(["tune", "--scenario", str(PAPER), "--out", str(out), "--ray", address])
            lines = capsys.readouterr().err.strip().splitlines()
            assert status == 2, address
            assert len(lines) == 1 and lines[0].startswith("swarm tune: "), lines
            assert expected in lines[0], lines[0]
            assert not out.exists()
        closing.join(timeout=5.0)


def test_without_ray_installed_the_error_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ClusterError, match=r"pip install \.\[cluster\]"):
        import_ray()

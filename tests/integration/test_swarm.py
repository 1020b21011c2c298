"""The three-robot swarm as real processes talking over a real Zenoh router on loopback.

Whatever depends on how fast the host runs the processes is asserted in lockstep
(`swarm up --lockstep`: the world waits for every live robot each tick, so a loaded machine only
makes a run slower): tracking and formation bounds, collisions, a killed robot's body, a
restarted robot's return to its slot.  Real-time runs assert only what does not depend on timing:
the processes come up, admin verbs answer, a killed robot leaves and a restarted one comes back,
counters agree with each other and with the run's length.  Wall-clock figures (deadline misses,
jitter, real-time factor) are measured by bench/swarm_runtime.py, not asserted here.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from robot_firmware import native
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from services.launcher.open_files import router_files_needed
from swarm_config.scenario import load_scenario
from tests.integration.conftest import (
    PAPER,
    ROOT,
    LiveSwarm,
    free_port,
    run_swarm,
    swarm_cli,
)
from tests.support.full_device import DEV_FULL, run_with_stdout_on_a_full_device
from tests.support.waiting import wait_for

pytestmark = pytest.mark.slow

SWARM = "lab"
_SCENARIO = load_scenario(PAPER)
ROBOTS = _SCENARIO.robot_names
CONTROL_PERIOD_S = _SCENARIO.controller_params().control_period_s
BROADCAST_RATE_HZ = _SCENARIO.radio.broadcast_rate_hz


def _assert_paper_bounds(summary: dict, formation_bound_m: float = 0.03) -> None:
    assert summary["leader_tracking_rms_m"] <= 0.02
    for name, value in summary["formation_rms_m"].items():
        assert value <= formation_bound_m, (name, value)
    assert summary["collisions"] == 0
    assert summary["min_obstacle_clearance_m"] > 0.0


def _query(live_swarm: LiveSwarm, target: str, verb: str) -> dict[str, Any]:
    """The JSON reply of `admin/<target>/<verb>`, or {} when nobody answered (yet)."""
    with open_client([live_swarm.endpoint]) as session:
        for reply in session.get(SwarmKeys(SWARM).admin(target, verb), timeout=3.0):
            if reply.ok is not None:
                data = json.loads(reply.ok.payload.to_bytes())
                return data if isinstance(data, dict) else {}
    return {}


def _world_status(live_swarm: LiveSwarm) -> dict[str, Any]:
    return _query(live_swarm, "world", "status") or {"live": [], "tick": -1}


def _left_the_world(live_swarm: LiveSwarm, robot: str) -> bool:
    """The world answers, and no longer counts `robot` among the live."""
    status = _query(live_swarm, "world", "status")
    return bool(status) and robot not in status["live"]


def _launcher_status(live_swarm: LiveSwarm) -> dict[str, Any]:
    """What `swarm status` prints, asked from this process: polling through the command line
    would start a Python process per poll, which a loaded host can take longer to start than
    the command's own time-out."""
    return _query(live_swarm, "launcher", "status")


def _all_running(live_swarm: LiveSwarm) -> dict[str, Any] | None:
    status = _launcher_status(live_swarm)
    if status.get("ok") and all(p["running"] for p in status["processes"].values()):
        return status
    return None


class TruthLog:
    """Every `truth` message the world publishes while it is open (poses and alive flags)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._messages: list[dict[str, Any]] = []

    def on_sample(self, sample: zenoh.Sample) -> None:  # a zenoh callback: store and return
        message = json.loads(sample.payload.to_bytes())
        with self._lock:
            self._messages.append(message)

    def messages(self) -> list[dict[str, Any]]:
        with self._lock:
            return list(self._messages)


@contextmanager
def _truth_log(live_swarm: LiveSwarm) -> Iterator[TruthLog]:
    log = TruthLog()
    with open_client([live_swarm.endpoint]) as session:
        subscriber = session.declare_subscriber(SwarmKeys(SWARM).truth, log.on_sample)
        try:
            yield log
        finally:
            subscriber.undeclare()


def test_lockstep_swarm_meets_the_paper_bounds_and_broadcasts_every_period(
    tmp_path: Path,
) -> None:
    duration_s = 60.0
    summary = run_swarm(tmp_path / "swarm", "--lockstep", "--duration", str(duration_s))
    assert summary["clock_mode"] == "lockstep"
    assert summary["duration_s"] == pytest.approx(duration_s)
    _assert_paper_bounds(summary)
    # In lockstep every robot answers every tick, so each broadcasts on every one of its
    # 20 Hz slots: 3 robots x 20 Hz x 60 s, and each broadcast reaches the two others.
    radio = summary["radio"]
    assert radio["broadcasts"] == round(len(ROBOTS) * BROADCAST_RATE_HZ * duration_s)
    assert radio["frames"] == (len(ROBOTS) - 1) * radio["broadcasts"]
    assert radio["delivered"] + radio["dropped"] == radio["frames"]
    assert summary["malformed_acts"] == 0


def test_lockstep_with_the_same_seed_is_bit_for_bit_repeatable(tmp_path: Path) -> None:
    """Also when the second run is paced (--max-speed): pacing only delays ticks."""
    first = run_swarm(tmp_path / "a", "--lockstep", "--duration", "8")
    run_swarm(tmp_path / "b", "--lockstep", "--max-speed", "4", "--duration", "8")
    assert (tmp_path / "a" / "summary.json").read_bytes() == (
        tmp_path / "b" / "summary.json"
    ).read_bytes()
    assert first["radio"]["delivered"] > 0


def test_swarm_up_typed_outside_the_repository_takes_its_relative_paths_from_there(
    tmp_path: Path,
) -> None:
    """The launcher starts its processes in the repository; the paths a user typed relative
    to another folder must still name the files there (before, the router refused the
    launcher's login and the run never started)."""
    shutil.copy(ROOT / "configs" / "scenarios" / "paper.yaml", tmp_path / "mine.yaml")
    port = free_port()
    result = subprocess.run(
        [str(ROOT / "swarm"), "up", "--scenario", "mine.yaml", "--out", "run", "--lockstep"]
        + ["--duration", "2", "--no-dashboard", "--port", str(port)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["duration_s"] == pytest.approx(2.0)
    assert summary["scenario"] == "paper"
    assert any((tmp_path / "run" / "logs").iterdir())
    assert not (ROOT / "run").exists()


def _lockstep_run(out: Path, seconds: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(ROOT / "swarm"), "up", "--out", str(out), "--lockstep", "--duration", str(seconds)]
        + ["--no-dashboard", "--port", str(free_port())],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=180,
    )


def test_a_second_run_in_the_same_folder_starts_afresh(tmp_path: Path) -> None:
    """`swarm up` twice on one run folder (the default runs/swarm, the quick start typed twice):
    the second run is a run of its own.  Before, its world resumed from the first run's last
    checkpoint, at the first run's end, and the second run ended at once with nothing run."""
    out = tmp_path / "run"
    first = _lockstep_run(out, 2)
    assert first.returncode == 0, first.stdout + first.stderr
    summary = (out / "summary.json").read_bytes()
    assert json.loads(summary)["world_resumes"] == []
    second = _lockstep_run(out, 2)
    assert second.returncode == 0, second.stdout + second.stderr
    assert (out / "summary.json").read_bytes() == summary  # lockstep: the same run again
    assert "the earlier run's checkpoints removed" in second.stderr
    assert "resuming from checkpoint" not in (out / "logs" / "world.log").read_text()


def test_a_world_that_cannot_write_its_files_runs_to_the_end_and_says_so(tmp_path: Path) -> None:
    """The run folder refuses every file the world writes (a folder where summary.json and
    events.jsonl go, a file where the checkpoints go), as a full disk would.  Before, the
    world died at its first periodic summary and the launcher restarted it every few
    seconds, each start dying the same way, while every robot stood still."""
    out = tmp_path / "run"
    (out / "summary.json").mkdir(parents=True)
    (out / "events.jsonl").mkdir()
    (out / "checkpoints").write_text("in the way")
    result = _lockstep_run(out, 3)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert f"the world could not write the run's final {out / 'summary.json'}" in result.stderr
    assert result.stderr.count("started world") == 1  # never died, never restarted
    assert "the world exited" not in result.stderr
    world_log = (out / "logs" / "world.log").read_text()
    for what in ("summary.json", "checkpoint", "events.jsonl"):
        assert world_log.count(f"{what} not written") == 1, world_log  # once for the streak
    assert "Traceback" not in world_log


def test_writes_that_failed_during_a_run_are_counted_in_its_summary(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "checkpoints").write_text("in the way")
    result = _lockstep_run(out, 2)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["duration_s"] == pytest.approx(2.0)
    assert set(summary["write_failures"]) == {"checkpoint"}
    assert summary["write_failures"]["checkpoint"] >= 4  # one every 0.5 s of simulated time


@pytest.mark.parametrize(("robots", "limit"), [(3, 12), (12, 32)])
def test_a_host_out_of_open_files_ends_the_start_in_one_line(
    tmp_path: Path, robots: int, limit: int
) -> None:
    """`swarm up` under an open-file limit too low for its router.  Under 12, the launcher
    could start the router but not the next process (a traceback from `subprocess` before
    that); under 32, 12 robots all started and the router, out of descriptors, let the world
    in never: the run waited without a word and wrote no summary."""
    port = free_port()
    scenario = tmp_path / "scenario.yaml"
    generate = [str(ROOT / "swarm"), "scenario", "generate", "--robots", str(robots)]
    subprocess.run([*generate, "--out", str(scenario)], check=True, capture_output=True, cwd=ROOT)

    def few_open_files() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (limit, limit))

    result = subprocess.run(
        [str(ROOT / "swarm"), "up", "--out", str(tmp_path / "run"), "--lockstep"]
        + ["--scenario", str(scenario), "--duration", "2", "--no-dashboard", "--port", str(port)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=180,
        preexec_fn=few_open_files,
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    needed = router_files_needed(robots + 2)  # with the world and the launcher
    assert last == (
        f"swarm up: this shell allows {limit} open files (`ulimit -Hn`), and the router needs "
        f"{needed} for {robots + 2} processes, so nothing was started (raise it with `ulimit "
        "-n`, or start fewer robots)"
    )
    assert not (tmp_path / "run" / "logs" / "router.log").exists()
    with socket.socket() as probe:  # nothing listens on the port
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # past TIME_WAIT
        probe.bind(("127.0.0.1", port))


def test_max_speed_without_lockstep_is_a_usage_error(tmp_path: Path) -> None:
    for command in (["up", "--out", str(tmp_path / "up")], ["world", "--duration", "1"]):
        refused = swarm_cli(*command, "--max-speed", "2")
        assert refused.returncode == 2, refused.stderr
        assert "max_speed" in refused.stderr.replace("-", "_")
        assert "lockstep" in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "up").exists()


def test_a_duration_that_never_ends_is_a_usage_error(tmp_path: Path) -> None:
    for value in ("inf", "nan", "1e400"):
        refused = swarm_cli("up", "--out", str(tmp_path / "up"), "--duration", value)
        assert refused.returncode == 2, refused.stderr
        assert "duration_s: Input should be a finite number" in refused.stderr
        assert "Traceback" not in refused.stderr
    assert not (tmp_path / "up").exists()  # nothing started


def test_a_port_outside_1_to_65535_is_a_usage_error(tmp_path: Path) -> None:
    # Before, `swarm up --port -1` started every process and the router died on its port.
    for command in (
        ("up", "--out", str(tmp_path / "up"), "--port", "-1"),
        ("up", "--out", str(tmp_path / "up"), "--port", "0"),
        ("up", "--out", str(tmp_path / "up"), "--web-port", "70000"),
        ("dashboard", "--grpc-port", "99999"),
        ("replay", str(tmp_path / "none.rrd"), "--web-port", "x"),
    ):
        refused = swarm_cli(*command)
        assert refused.returncode == 2, (command, refused.stderr)
        assert "is not a TCP port (1-65535)" in refused.stderr, refused.stderr
    assert not (tmp_path / "up").exists()


def test_commands_without_a_swarm_say_so_instead_of_waiting(tmp_path: Path) -> None:
    # Before, `swarm status` with no swarm running waited for a router forever.
    credentials = tmp_path / "credentials"
    made = swarm_cli("credentials", str(credentials), "--scenario", str(PAPER))
    assert made.returncode == 0, made.stderr
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    operator = str(credentials / "operator.json")
    for command in (("status",), ("kill", "robot3"), ("regs", "robot1", "0xFF200010")):
        started = time.monotonic()
        refused = swarm_cli(
            *command, "--connect", endpoint, "--credentials", operator, "--timeout", "1", timeout=30
        )
        assert refused.returncode == 2, (command, refused.stderr)
        assert f"no router at {endpoint} let the operator in within 5 s" in refused.stderr
        assert "Traceback" not in refused.stderr
        assert time.monotonic() - started < 25  # generous: a loaded machine starts Python slowly


def test_a_login_the_router_refuses_is_one_line_on_stderr_and_nothing_on_stdout(
    tmp_path: Path,
) -> None:
    # Before, Zenoh's own error lines for the refused login went to the command's stdout,
    # into whatever read it (`swarm status robot1 | jq`), ahead of the command's own answer.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    for run in ("this", "another"):
        made = swarm_cli("credentials", str(tmp_path / run), "--listen", endpoint)
        assert made.returncode == 0, made.stderr
    log_path = tmp_path / "router.log"
    with log_path.open("wb") as log:
        router = subprocess.Popen(
            [sys.executable, "-m", "services.cli.main", "router"]
            + ["--config", str(tmp_path / "this" / "router.json5")],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
        )
    try:
        wait_for(lambda: "router listening" in log_path.read_text(), timeout_s=30)
        another_operator = str(tmp_path / "another" / "operator.json")
        for command in (("status",), ("status", "robot1"), ("regs", "robot1")):
            refused = swarm_cli(*command, "--connect", endpoint, "--credentials", another_operator)
            assert refused.returncode == 2, (command, refused.stderr)
            assert refused.stdout == "", (command, refused.stdout)
            lines = refused.stderr.splitlines()
            assert len(lines) == 1 and f"no router at {endpoint}" in lines[0], refused.stderr
    finally:
        router.terminate()
        router.wait(timeout=30)


@pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full on this system")
def test_swarm_up_with_stdout_on_a_full_device_runs_to_its_end(tmp_path: Path) -> None:
    # Before, the first line it printed after starting the swarm raised, and the launcher took
    # every process down with it: no run, a traceback, status 1.
    out = tmp_path / "run"
    ran = run_with_stdout_on_a_full_device(
        ["up", "--out", str(out), "--port", str(free_port())]
        + ["--no-dashboard", "--lockstep", "--duration", "2"],
        ROOT,
    )
    assert ran.returncode == 1, ran.stderr
    assert "Traceback" not in ran.stderr, ran.stderr
    assert ran.stderr.count("swarm up: cannot write to standard output") == 1, ran.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["duration_s"] == pytest.approx(2.0)


def _files_of(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_swarm_up_on_a_taken_port_says_so_and_starts_nothing_else(tmp_path: Path) -> None:
    """Before, the launcher waited forever for a router that had died, deaf to Ctrl-C; and
    then, refusing in one line, it had already written the run folder: a new folder came with
    credentials, a scenario copy and logs/, and an earlier run's folder lost its checkpoints
    and credentials."""
    earlier = tmp_path / "earlier"
    first = _lockstep_run(earlier, 1)
    assert first.returncode == 0, first.stdout + first.stderr
    assert list((earlier / "checkpoints").iterdir())
    files = _files_of(earlier)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        refused = {
            out: swarm_cli("up", "--no-dashboard", "--out", str(out), "--port", str(port))
            for out in (tmp_path / "new", earlier)
        }
    for out, result in refused.items():
        assert result.returncode == 1, (out, result.stderr)
        assert result.stderr == (
            f"swarm up: cannot listen on tcp/127.0.0.1:{port}: Address already in use, so "
            "nothing was started (another program or swarm listens there; `swarm up --port N` "
            "picks another)\n"
        )
    assert not (tmp_path / "new").exists()
    assert _files_of(earlier) == files


def _listens(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def test_swarm_up_on_another_swarms_port_prints_one_line_and_no_zenoh_log(tmp_path: Path) -> None:
    # Before, the launcher's session tried the other swarm's router before its own router had
    # failed to listen, and Zenoh logged that router's refusals on the user's terminal.
    other = tmp_path / "other"
    made = swarm_cli("credentials", str(other), "--scenario", str(PAPER))
    assert made.returncode == 0, made.stderr
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli.main", "router", "--listen", endpoint]
        + ["--config", str(other / "router.json5")],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_for(lambda: _listens(port) or router.poll() is not None, timeout_s=60)
        assert router.poll() is None, "the other swarm's router did not start"
        out = str(tmp_path / "up")
        refused = swarm_cli("up", "--no-dashboard", "--out", out, "--port", str(port))
    finally:
        router.terminate()
        router.wait(timeout=30)
    assert refused.returncode == 1, refused.stderr
    assert refused.stderr.startswith(f"swarm up: cannot listen on {endpoint}: Address already in")
    assert len(refused.stderr.splitlines()) == 1, refused.stderr


def test_real_time_swarm_reports_loop_timing_consistent_with_its_length(tmp_path: Path) -> None:
    # How many deadlines a loaded host misses is bench/swarm_runtime.py's figure; here the
    # counters must be there and agree with each other and with the length of the run.
    summary = run_swarm(tmp_path / "rt", "--duration", "32")
    assert summary["clock_mode"] == "real_time"
    assert summary["duration_s"] == pytest.approx(32.0, abs=2 * CONTROL_PERIOD_S)
    periods = round(summary["duration_s"] / CONTROL_PERIOD_S)
    for name in ROBOTS:
        timing = summary["control_timing"][name]
        assert timing is not None, name
        # A tick never starts less than a period after the one before, so a robot counts at
        # most one tick per control period of the run (plus the few periods between the end of
        # the world's loop and its reading the last telemetry).
        assert 0 < timing["ticks"] <= periods + 50, (name, timing, periods)
        misses = timing["recent_miss_ticks"]
        assert len(misses) == min(timing["deadline_misses"], 10), (name, timing)
        assert misses == sorted(set(misses)), (name, timing)
        assert all(1 <= tick <= timing["ticks"] for tick in misses), (name, timing)
        assert timing["period_jitter_p99_ms"] >= 0.0, (name, timing)
    radio = summary["radio"]
    assert 0 < radio["broadcasts"] <= round(len(ROBOTS) * BROADCAST_RATE_HZ * 32.0) + len(ROBOTS)
    assert radio["frames"] <= (len(ROBOTS) - 1) * radio["broadcasts"]
    assert summary["malformed_acts"] == 0


def test_lossy_radio_keeps_the_formation_within_six_centimetres(tmp_path: Path) -> None:
    summary = run_swarm(tmp_path / "lossy", "--lockstep", "--duration", "60", "--radio", "lossy")
    radio = summary["radio"]
    assert radio["profile"]["loss"] == 0.2
    assert 0.77 <= radio["delivery_ratio"] <= 0.83
    _assert_paper_bounds(summary, formation_bound_m=0.06)


def test_status_regs_and_net_on_a_running_swarm(live_swarm: LiveSwarm) -> None:
    status = live_swarm.all_running()
    assert set(status["processes"]) == {"router", "world", "robot1", "robot2", "robot3"}
    # A running process may still be importing; a robot answers once it is up (and the world
    # counts it live from then on).
    live_swarm.wait_for(lambda: len(_world_status(live_swarm)["live"]) == len(ROBOTS))

    dump = live_swarm.cli("regs", "robot1")
    assert dump.returncode == 0, dump.stderr
    assert "sysid.ID" in dump.stdout and "0x5357524D" in dump.stdout
    assert "pwm0.DUTY_TICKS" in dump.stdout
    one = live_swarm.cli("regs", "robot1", "0xFF200000")
    assert one.returncode == 0 and "0x5357524D" in one.stdout
    scratch = live_swarm.cli("regs", "robot2", "0xFF200010", "0xCAFE")
    assert scratch.returncode == 0, scratch.stderr
    assert "0x0000CAFE" in live_swarm.cli("regs", "robot2", "0xFF200010").stdout
    refused = live_swarm.cli("regs", "robot1", "0xFF200000", "1")
    assert refused.returncode == 1 and "bus error" in refused.stderr
    unmapped = live_swarm.cli("regs", "robot1", "0xFF2FFFF0")
    assert unmapped.returncode == 1 and "unmapped" in unmapped.stderr
    nobody = live_swarm.cli("regs", "robot9")
    assert nobody.returncode == 2 and "no answer" in nobody.stderr

    before = live_swarm.admin("net", "get")["profile"]
    bad = live_swarm.cli("net", "set", "--loss", "1.5")
    assert bad.returncode == 1 and "invalid network profile" in bad.stdout
    assert live_swarm.admin("net", "get")["profile"] == before
    changed = live_swarm.admin(
        "net", "set", "--latency-ms", "50", "--jitter-ms", "20", "--loss", "0.2"
    )
    assert changed["ok"] and changed["profile"]["latency_ms"] == 50.0
    assert live_swarm.admin("net", "get")["profile"]["loss"] == 0.2
    # A fault on the links shows beside the profile it changes, until `heal` (before, `net
    # get` and the world's status showed the profile alone).
    assert live_swarm.admin("net", "get")["faults"] is None
    assert live_swarm.admin("fault", "net", "--robot", "robot3", "--loss", "0.9")["ok"]
    faults = live_swarm.admin("net", "get")["faults"]
    robot3 = {"links": [["robot1", "robot3"], ["robot2", "robot3"]], "loss": 0.9}
    unset = {"latency_ms": None, "jitter_ms": None, "burst": None}
    assert faults == {"overrides": [{**robot3, **unset}], "cut_links": []}, faults
    assert _world_status(live_swarm)["network_faults"] == faults
    assert live_swarm.admin("fault", "heal")["ok"]
    assert live_swarm.admin("net", "get")["faults"] is None
    assert live_swarm.admin("net", "get")["profile"]["loss"] == 0.2  # heal keeps `net set`

    # A second `swarm up` on this run's directory (on another port) is refused before it
    # writes anything: before, it wrote new credentials over this run's, so the command line
    # could no longer log in, and truncated its router log.
    operator_file = live_swarm.out / "credentials" / "operator.json"
    credentials_before = operator_file.read_bytes()
    router_log_before = (live_swarm.out / "logs" / "router.log").read_bytes()
    second = swarm_cli(
        "up", "--no-dashboard", "--out", str(live_swarm.out), "--port", str(free_port())
    )
    assert second.returncode == 2, second.stderr
    assert "another `swarm up` that is still running (pid" in second.stderr, second.stderr
    assert "Traceback" not in second.stderr
    assert operator_file.read_bytes() == credentials_before
    assert (live_swarm.out / "logs" / "router.log").read_bytes().startswith(router_log_before)
    assert live_swarm.admin("status")["ok"]


ZENOH_RUNTIME_THREAD_PREFIXES = ("app-", "acc-", "tx-", "rx-", "net-")
"""How Zenoh names the threads of its runtimes (application, acceptor, transmit, receive,
network)."""


def _zenoh_runtime_threads(pid: int) -> list[str]:
    names = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
        except (FileNotFoundError, ProcessLookupError):  # the thread ended meanwhile
            continue
        if name.startswith(ZENOH_RUNTIME_THREAD_PREFIXES):
            names.append(name)
    return sorted(names)


def test_every_swarm_process_runs_zenoh_on_one_runtime(live_swarm: LiveSwarm) -> None:
    """The world and each robot hand Zenoh's receive, transmit, acceptor and network runtimes
    over to the application runtime, one thread; the router hands the others over to its
    receive runtime, two threads, so that a forward waiting on a congested link leaves the
    other thread to the rest (robot_firmware/net/session.py)."""
    processes = live_swarm.all_running()["processes"]
    live_swarm.wait_for(lambda: len(_world_status(live_swarm)["live"]) == len(ROBOTS))
    threads = {name: _zenoh_runtime_threads(process["pid"]) for name, process in processes.items()}
    assert set(threads) == {"router", "world", *ROBOTS}
    for name in ("world", *ROBOTS):
        assert "app-0" in threads[name], (name, threads[name])
        assert all(thread.startswith("app-") for thread in threads[name]), (name, threads[name])
    assert {"rx-0", "rx-1"} <= set(threads["router"]), threads["router"]
    assert all(thread.startswith("rx-") for thread in threads["router"]), threads["router"]


def test_the_robots_of_swarm_up_run_the_compiled_register_model(live_swarm: LiveSwarm) -> None:
    """`swarm up` asks its robots for the mypyc build of the register model and drivers
    (robot_firmware/native.py): each says so in its status, and maps the build's files."""
    hash_ = native.source_hash()
    if native.load_manifest(hash_) is None:
        pytest.skip("no mypyc build for these sources (scripts/ensure-env.sh makes it)")
    processes = live_swarm.all_running()["processes"]
    build = str(native.build_dir(hash_))
    for name in ROBOTS:
        status = live_swarm.wait_for(lambda name=name: _query(live_swarm, name, "status"))
        assert status["register_model"] == "mypyc", name
        maps = Path(f"/proc/{processes[name]['pid']}/maps").read_text()
        assert build in maps, name
    world_maps = Path(f"/proc/{processes['world']['pid']}/maps").read_text()
    assert build not in world_maps


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGHUP], ids=["sigkill", "sighup"])
def test_a_launcher_killed_or_hung_up_takes_its_whole_swarm_with_it(
    live_swarm: LiveSwarm, how: signal.Signals
) -> None:
    """`kill -9` of `swarm up` (no orderly stop) and a closed terminal (SIGHUP): before, the
    router, the world and the robots ran on unsupervised, holding the port.  Now every child
    ends too, the world after writing its final summary."""
    children = {
        name: process["pid"] for name, process in live_swarm.all_running()["processes"].items()
    }
    live_swarm.wait_for(lambda: (live_swarm.out / "summary.json").exists(), 60)
    summary_before = (live_swarm.out / "summary.json").stat().st_mtime_ns
    live_swarm.process.send_signal(how)
    live_swarm.process.wait(timeout=60)
    live_swarm.wait_for(
        lambda: not any(_pid_alive(pid) for pid in children.values()),
        timeout_s=60,
        describe=f"every child of the launcher gone after {how.name}: {children}",
    )
    assert (live_swarm.out / "summary.json").stat().st_mtime_ns > summary_before
    world_log = (live_swarm.out / "logs" / "world.log").read_text()
    assert "Traceback" not in world_log
    if how == signal.SIGHUP:
        assert live_swarm.process.returncode == 0
    # The port is free again: a new swarm can take the same directory and port.
    assert run_swarm(live_swarm.out, "--duration", "1", port=live_swarm.port)["clock_mode"]


def test_killed_robot_leaves_and_a_restarted_one_comes_back(live_swarm: LiveSwarm) -> None:
    live_swarm.wait_for(lambda: _all_running(live_swarm))
    live_swarm.wait_for(lambda: len(_world_status(live_swarm)["live"]) == len(ROBOTS))
    killed = live_swarm.admin("kill", "robot2")
    assert killed == {"ok": True, "killed": True}
    processes = _launcher_status(live_swarm)["processes"]
    assert not processes["robot2"]["running"] and processes["robot2"]["killed"]
    assert processes["robot1"]["running"] and processes["robot3"]["running"]
    # Its liveliness token goes with the process: the world counts it out.
    live_swarm.wait_for(lambda: _left_the_world(live_swarm, "robot2"))
    # A question to it says why nobody answers (before: "is it running? start one with
    # `swarm up`", with the swarm running).
    silent = live_swarm.cli("status", "robot2", "--timeout", "1")
    assert silent.returncode == 2, silent.stderr
    assert "it was killed and stays down: `swarm restart robot2`" in silent.stderr
    assert "start one with" not in silent.stderr
    restarted = live_swarm.admin("restart", "robot2")
    assert restarted["ok"] and restarted["restarted"] == "robot2"
    live_swarm.wait_for(lambda: _launcher_status(live_swarm)["processes"]["robot2"]["running"])
    log = live_swarm.out / "logs" / "robot2.log"
    live_swarm.wait_for(lambda: log.read_text().count("robot robot2 up") == 2)
    live_swarm.wait_for(lambda: "robot2" in _world_status(live_swarm)["live"])
    # The new process re-localises from the positioning fix.
    live_swarm.wait_for(lambda: _query(live_swarm, "robot2", "status").get("localised"))
    unknown = live_swarm.cli("kill", "robot7")
    assert unknown.returncode == 1 and "no process 'robot7'" in unknown.stdout


def test_a_stopped_launcher_is_named_when_it_does_not_answer(live_swarm: LiveSwarm) -> None:
    """Before: "no answer from launcher ... (is it running? start one with `swarm up`)", with
    the swarm running and its launcher stopped with `kill -STOP`."""
    live = live_swarm
    live.all_running()
    pid = live.process.pid
    os.kill(pid, signal.SIGSTOP)
    try:
        silent = live.cli("status", "--timeout", "1")
    finally:
        os.kill(pid, signal.SIGCONT)
    assert silent.returncode == 2, silent.stderr
    assert (
        f"(the launcher of this run (pid {pid}) is stopped: `kill -CONT {pid}` continues it)"
        in silent.stderr
    ), silent.stderr
    live.all_running()  # continued, it answers again


def test_a_world_stopped_from_outside_the_launcher_is_started_again(live_swarm: LiveSwarm) -> None:
    """`kill PID` of the world (SIGTERM from a user or a service manager, not the launcher).
    Before, the world wrote its final summary and exited 0, which the launcher took for the
    run's end: `swarm up` ended at once with status 0, the run cut short without a word.  Now
    it is a death like a `kill -9`: the launcher starts the world again, and it resumes."""
    live = live_swarm
    processes = live.all_running()["processes"]
    live.wait_for(lambda: _world_status(live)["tick"] > 100, describe="world time")
    old_pid = processes["world"]["pid"]
    os.kill(old_pid, signal.SIGTERM)

    def restarted_world() -> dict[str, Any] | None:
        assert live.process.poll() is None, "swarm up ended: the run was cut short"
        world = _launcher_status(live).get("processes", {}).get("world")
        return world if world and world["running"] and world["pid"] != old_pid else None

    world = live.wait_for(restarted_world, describe="the world started again")
    assert world["restarts"] == 1 and not world["killed"]
    assert live.process.poll() is None  # the run goes on
    live.wait_for(lambda: _world_status(live)["tick"] > 0, describe="the new world")
    log = (live.out / "logs" / "world.log").read_text()
    assert "resuming from checkpoint" in log, log[-2000:]


# Paced at (at most) one simulated second per wall second: an unpaced lockstep world and its
# robots take all the CPU they can get, which starves the `swarm restart` command on a loaded
# host; pacing changes no result, only how long the run takes.
@pytest.mark.parametrize("live_swarm", [("--lockstep", "--max-speed", "1")], indirect=True)
def test_lockstep_killed_robot_is_a_power_cut_and_a_restarted_one_rejoins(
    live_swarm: LiveSwarm,
) -> None:
    def world() -> dict[str, Any]:
        return _world_status(live_swarm)

    first = live_swarm.wait_for(lambda: (s := world()) and len(s["live"]) == len(ROBOTS) and s)
    assert first["clock_mode"] == "lockstep"
    with _truth_log(live_swarm) as truth:
        assert live_swarm.admin("kill", "robot3")["killed"]
        live_swarm.wait_for(lambda: _left_the_world(live_swarm, "robot3"))
        # The world does not wait for a dead robot: time goes on without it.
        after_kill = world()["tick"]
        live_swarm.wait_for(lambda: world()["tick"] > after_kill + 300)
        # A power cut: no more duty reaches its motors, which spin down within a few motor time
        # constants (50 ms); from then on its body stays where it stopped.
        dead = [
            m["robots"]["robot3"]["pose"]
            for m in truth.messages()
            if not m["robots"]["robot3"]["alive"] and m["tick"] >= after_kill + 100
        ]
    assert len(dead) >= 10, len(dead)
    for pose in dead[1:]:
        assert abs(pose[0] - dead[0][0]) < 1e-4 and abs(pose[1] - dead[0][1]) < 1e-4, pose
        assert abs(pose[2] - dead[0][2]) < 1e-3, pose
    live_swarm.admin("restart", "robot3")
    live_swarm.wait_for(lambda: "robot3" in world()["live"])
    rejoined = world()["tick"]
    live_swarm.wait_for(lambda: world()["tick"] > rejoined + 100)
    # It boots, re-localises from the positioning fix and drives back into its slot.
    live_swarm.wait_for(lambda: world()["position_errors_m"]["robot3"] < 0.05)
    metrics = world()["metrics"]
    assert metrics["collisions"] == 0, metrics
    assert metrics["min_robot_separation_m"] > 0.0, metrics


@pytest.mark.parametrize("live_swarm", [("--lockstep", "--max-speed", "0.002")], indirect=True)
def test_paced_lockstep_keeps_its_pace_and_answers_queries_between_ticks(
    live_swarm: LiveSwarm,
) -> None:
    """At 0.002 simulated s per wall s a 10 ms tick is due every 5 s of wall time; the world
    still answers admin queries (3 s time-out) while it waits."""
    first = live_swarm.wait_for(lambda: (s := _world_status(live_swarm)) and s["tick"] > 0 and s)
    started_s = time.monotonic()
    live_swarm.wait_for(lambda: _world_status(live_swarm)["tick"] > first["tick"])
    for _ in range(5):
        status = _world_status(live_swarm)
        assert status["clock_mode"] == "lockstep"
    elapsed_s = time.monotonic() - started_s
    ticks = _world_status(live_swarm)["tick"] - first["tick"]
    assert 1 <= ticks <= elapsed_s / 5.0 + 2, (ticks, elapsed_s)


def test_fuzzy_parameters_are_replaced_on_a_live_robot(
    live_swarm: LiveSwarm, tmp_path: Path
) -> None:
    live_swarm.wait_for(lambda: "parameters" in live_swarm.admin("params", "robot2"), 60)
    current = live_swarm.admin("params", "robot2")["parameters"]
    assert len(current["error_centres"]) == 7
    good = tmp_path / "good.yaml"
    good.write_text("error_centres: [-1.0, 0.0, 1.0]\nrate_centres: [-1.0, -0.3, 0.3, 1.0]\n")
    reply = live_swarm.admin("params", "robot2", str(good))
    assert reply["ok"] is True and reply["rule_count"] == 12, reply
    assert live_swarm.admin("params", "robot2")["parameters"]["error_centres"] == [-1, 0, 1]
    bad = tmp_path / "bad.yaml"
    bad.write_text("error_centres: [1.0, 0.0]\nrate_centres: [-1.0, 1.0]\n")
    refused = live_swarm.cli("params", "robot2", str(bad), "--swarm", "lab")
    assert refused.returncode == 1 and "strictly increasing" in refused.stdout
    assert live_swarm.admin("params", "robot2")["parameters"]["error_centres"] == [-1, 0, 1]


def test_clients_reconnect_after_the_router_restarts(live_swarm: LiveSwarm) -> None:
    status = live_swarm.wait_for(lambda: _all_running(live_swarm))
    live_swarm.wait_for(lambda: len(_world_status(live_swarm)["live"]) == len(ROBOTS))
    os.kill(status["processes"]["router"]["pid"], signal.SIGKILL)
    restarted = live_swarm.wait_for(
        lambda: (
            (s := live_swarm.admin("status")).get("ok")
            and s["processes"]["router"]["restarts"] == 1
            and s["processes"]["router"]["running"]
            and s
        )
    )
    assert restarted["processes"]["router"]["pid"] != status["processes"]["router"]["pid"]
    # World and robots find the new router, re-declare their tokens and carry on: the world
    # ticks, and every robot answers its queries and hears its peers' frames again.
    world = live_swarm.wait_for(
        lambda: len((s := _world_status(live_swarm))["live"]) == len(ROBOTS) and s
    )
    live_swarm.wait_for(lambda: _world_status(live_swarm)["tick"] > world["tick"] + 100)
    for name in ROBOTS:
        heard = live_swarm.wait_for(lambda name=name: _query(live_swarm, name, "status"))
        accepted = heard["frames"]["accepted"]
        live_swarm.wait_for(
            lambda name=name, accepted=accepted: (
                _query(live_swarm, name, "status").get("frames", {}).get("accepted", 0)
                > accepted + 10
            )
        )
    # The same through the command line.  Before, `swarm kill router` and `swarm restart
    # router` did it and then said "no answer from launcher ... (is it running?)", status 2:
    # the answer went down with the router.
    pid = restarted["processes"]["router"]["pid"]
    for restarts, verb in enumerate(("kill", "restart"), start=2):
        done = live_swarm.cli(verb, "router")
        assert done.returncode == 0, done.stderr
        assert f"no answer through the router after `{verb} router`" in done.stderr
        router = json.loads(done.stdout)["processes"]["router"]
        assert router["restarts"] == restarts and router["running"] and router["pid"] != pid
        pid = router["pid"]


def test_swarm_up_with_its_dashboards_port_taken_says_so_and_starts_nothing(
    tmp_path: Path,
) -> None:
    # Before, the swarm ran, printed the dashboard's URL, and the dashboard exited at once.
    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("0.0.0.0", 0))
        taken.listen()
        web_port = taken.getsockname()[1]
        out = tmp_path / "up"
        argv = ["up", "--out", str(out), "--port", str(free_port()), "--duration", "3"]
        refused = swarm_cli(*argv, "--web-port", str(web_port), "--grpc-port", str(free_port()))
    assert refused.returncode == 1, refused.stderr
    assert refused.stderr.startswith(
        f"swarm up: the dashboard cannot serve on port {web_port} (--web-port): Address already"
    ), refused.stderr
    assert "--no-dashboard to run without it" in refused.stderr
    assert not out.exists()  # nothing written, as for a taken --port


def _stopped(live_swarm: LiveSwarm, name: str) -> bool | None:
    """The launcher's `stopped` for `name`, None when it did not answer."""
    process = _launcher_status(live_swarm).get("processes", {}).get(name)
    return None if process is None else bool(process["stopped"])


def test_the_launcher_reports_stops_and_continues_made_outside_it(live_swarm: LiveSwarm) -> None:
    """Before, the launcher's status knew only its own SIGSTOPs: a robot stopped with `kill
    -STOP` showed as running, and one continued with `kill -CONT` after `swarm fault stop`
    (what that command names for the router) stayed "stopped" for good."""
    live = live_swarm
    processes = live.all_running()["processes"]
    pid = processes["robot2"]["pid"]
    os.kill(pid, signal.SIGSTOP)
    try:
        live.wait_for(lambda: _stopped(live, "robot2"), describe="robot2 shown stopped")
    finally:
        os.kill(pid, signal.SIGCONT)
    live.wait_for(lambda: _stopped(live, "robot2") is False, describe="robot2 shown running")
    stopped = live.cli("fault", "stop", "robot3")
    assert stopped.returncode == 0, stopped.stderr
    live.wait_for(lambda: _stopped(live, "robot3"), describe="robot3 shown stopped")
    os.kill(processes["robot3"]["pid"], signal.SIGCONT)
    live.wait_for(lambda: _stopped(live, "robot3") is False, describe="robot3 shown running")


def test_a_world_stopped_from_outside_still_writes_its_own_final_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before, the launcher sent SIGCONT after its SIGTERM only to a process it had stopped
    itself: a world stopped with `kill -STOP` got SIGKILL after the grace time at the end of
    the run, and the run's summary was its last checkpoint's."""
    out, port = tmp_path / "run", free_port()
    up = subprocess.Popen(
        [str(ROOT / "swarm"), "up", "--out", str(out), "--port", str(port), "--duration"]
        + ["600", "--no-dashboard"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        live = LiveSwarm(up, port, out)
        operator = out / "credentials" / "operator.json"
        live.wait_for(operator.exists, describe="the run's credentials")
        monkeypatch.setenv("SWARM_CREDENTIALS_FILE", str(operator))
        world_pid = live.wait_for(
            lambda: (s := _all_running(live)) and s["processes"]["world"]["pid"],
            describe="the swarm running",
        )
        live.wait_for(lambda: _world_status(live)["tick"] > 0, describe="the world ticking")
        os.kill(world_pid, signal.SIGSTOP)
        up.send_signal(signal.SIGTERM)
        _, stderr = up.communicate(timeout=120)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    assert up.returncode == 0, stderr
    assert "did not end within" not in stderr
    world_log = (out / "logs" / "world.log").read_text(encoding="utf-8")
    assert "world ended at t = " in world_log and "final summary written" in world_log
    assert json.loads((out / "summary.json").read_text(encoding="utf-8"))["duration_s"] > 0.0


def test_a_stopped_router_is_continued_with_the_pid_swarm_fault_names(
    live_swarm: LiveSwarm,
) -> None:
    # Before, `swarm fault stop router` left no way back through the swarm's own commands,
    # and nothing said which process to continue.
    live = live_swarm
    router_pid = live.all_running()["processes"]["router"]["pid"]
    stopped = live.cli("fault", "stop", "router")
    assert f"continues: `kill -CONT {router_pid}`" in stopped.stderr, stopped.stderr
    refused = live.cli("status")
    assert refused.returncode == 2
    assert "or its router is stopped (`swarm fault stop router`" in refused.stderr
    os.kill(router_pid, signal.SIGCONT)
    assert live.all_running()["processes"]["router"]["pid"] == router_pid

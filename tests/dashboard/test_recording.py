"""A real swarm with dashboards beside it: what lands in dashboard.rrd, and what a kill leaves.

One lockstep run of the paper scenario is watched by two dashboards: A runs to the end and is
stopped with SIGTERM; B is killed with SIGKILL mid-run and started again on the same directory.
A second run of the same swarm without dashboards (and not paced by `--max-speed`) must end
with the same summary.json, byte for byte: the dashboards only listen.
"""

from __future__ import annotations

import json
import signal
import socket
import urllib.request
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from rerun.error_utils import RerunWarning

from services.dashboard.recording_file import STREAM_HEADER_BYTES, whole_messages
from tests.dashboard.conftest import (
    Child,
    EntityData,
    free_port,
    read_recording,
    start,
    start_dashboard,
    start_swarm,
)
from tests.support.waiting import wait_for

pytestmark = pytest.mark.slow

ROBOTS = ("robot1", "robot2", "robot3")
FOLLOWERS = ("robot2", "robot3")
DURATION_S = 10.0


@dataclass
class RecordedRun:
    swarm_dir: Path
    full: Path
    cut: Path
    resumed: Path
    dashboard_exit_codes: tuple[int, int]
    reference_dir: Path
    restart_output: str


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RecordedRun]:
    base = tmp_path_factory.mktemp("dashboard-run")
    logs = base / "logs"
    port = free_port()
    started: list[Child] = []
    try:
        full = start_dashboard("dashboard-a", base / "a", port, logs)
        started.append(full.child)
        cut = start_dashboard("dashboard-b", base / "b", port, logs)
        started.append(cut.child)
        # Paced at real speed so the restarted dashboard has time to join before the end.
        swarm = start_swarm(
            base / "swarm", port, "--lockstep", "--max-speed", "1", "--duration", str(DURATION_S)
        )
        started.append(swarm)
        swarm.wait_for_line("swarm lab:", timeout_s=60)
        partial = base / "b" / "dashboard.rrd"
        wait_for(
            lambda: _recorded_until_s(partial) > 2.0, 90, 0.2, describe="dashboard B to record 2 s"
        )
        cut.child.stop(signal.SIGKILL)
        restarted = start_dashboard("dashboard-b2", base / "b", port, logs)
        started.append(restarted.child)
        assert swarm.process.wait(timeout=180) == 0, swarm.output()
        codes = (full.child.stop(), restarted.child.stop())

        reference = start_swarm(
            base / "reference", free_port(), "--lockstep", "--duration", str(DURATION_S)
        )
        started.append(reference)
        assert reference.process.wait(timeout=180) == 0, reference.output()
        yield RecordedRun(
            swarm_dir=base / "swarm",
            full=base / "a" / "dashboard.rrd",
            cut=base / "b" / "dashboard-1.rrd",
            resumed=base / "b" / "dashboard.rrd",
            dashboard_exit_codes=codes,
            reference_dir=base / "reference",
            restart_output=restarted.child.output(),
        )
    finally:
        for child in reversed(started):
            child.shut_down()


def _recorded_until_s(path: Path) -> float:
    """Latest simulated time of robot1's pose in a recording still being written.

    The writer may be in the middle of a message: only the whole ones are read, from a copy.
    """
    snapshot = path.with_name("poll-snapshot.rrd")
    snapshot.write_bytes(whole_messages(path) if path.exists() else b"")
    if snapshot.stat().st_size <= STREAM_HEADER_BYTES:
        return 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RerunWarning)
        robot = read_recording(snapshot).get("/map/robots/robot1")
    return max(robot.sim_times_s, default=0.0) if robot else 0.0


@pytest.fixture(scope="module")
def full_recording(recorded_run: RecordedRun) -> dict[str, EntityData]:
    return read_recording(recorded_run.full)


def _in_run(times_s: list[float]) -> bool:
    return bool(times_s) and min(times_s) >= 0.0 and max(times_s) <= DURATION_S + 0.1


def test_dashboards_stop_cleanly_on_sigterm(recorded_run: RecordedRun) -> None:
    assert recorded_run.dashboard_exit_codes == (0, 0)


def test_every_robot_pose_is_on_the_simulation_timeline(
    full_recording: dict[str, EntityData],
) -> None:
    for name in ROBOTS:
        robot = full_recording[f"/map/robots/{name}"]
        assert {"Points2D:positions", "Arrows2D:vectors", "Ellipses2D:centers"} <= (
            robot.components
        )
        assert _in_run(robot.sim_times_s), name
        # Truth at 20 Hz from t = 0 to the end of the run.
        assert min(robot.sim_times_s) <= 0.1 and max(robot.sim_times_s) >= DURATION_S - 0.1
        assert robot.rows >= 0.9 * 20 * DURATION_S, (name, robot.rows)
        assert "LineStrips2D:strips" in robot.components
        assert _in_run(full_recording[f"/map/robots/{name}/estimate"].sim_times_s)


def test_leader_and_formation_errors_are_the_run_metrics(
    full_recording: dict[str, EntityData],
) -> None:
    leader = full_recording["/errors/leader"].values("Scalars:scalars")
    formation = full_recording["/errors/formation"].values("Scalars:scalars")
    assert _in_run([t for t, _ in leader]) and _in_run([t for t, _ in formation])
    assert all(len(v) == 2 for _, v in leader)  # position (m), heading (rad)
    assert all(len(v) == len(FOLLOWERS) for _, v in formation)
    # The paper scenario starts everyone away from the formation; it converges in seconds.
    first_t, first = formation[0]
    assert first_t < 0.5 and min(first) > 0.3, first
    settled = [v for t, v in formation if 2.5 <= t <= 4.0]
    assert settled and max(max(v) for v in settled) < 0.1, settled
    assert leader[0][1][0] > 0.3  # the leader starts 0.57 m from its reference point


def test_scheduled_gains_of_every_robot_are_recorded(
    full_recording: dict[str, EntityData],
) -> None:
    for gain in ("kp", "ki", "kd"):
        for name in ROBOTS:
            rows = full_recording[f"/gains/{gain}/{name}"].values("Scalars:scalars")
            assert _in_run([t for t, _ in rows]), (gain, name)
            assert len(rows) >= 0.9 * 20 * DURATION_S
            assert all(len(v) == 3 for _, v in rows)  # axes x, y, theta
    kp = [v for _, v in full_recording["/gains/kp/robot2"].values("Scalars:scalars")]
    assert len({round(x, 6) for v in kp for x in v}) > 3, "the fuzzy scheduler moved K_P"


def test_radio_delivery_ratio_and_map_layers_are_recorded(
    full_recording: dict[str, EntityData],
) -> None:
    ratios = [v for _, v in full_recording["/radio/delivery_ratio"].values("Scalars:scalars")]
    cumulative = [v[0] for v in ratios if v[0] == v[0]]  # NaN until the first frame
    assert cumulative and 0.9 <= cumulative[-1] <= 1.0  # the lab profile loses 1 %
    latency = full_recording["/radio/latency_ms/configured"].values("Scalars:scalars")
    assert latency[-1][1] == [3.0, 5.0]  # lab profile: 3 ms + 2 ms jitter
    for path in ("/map", "/map/obstacles", "/map/obstacles/influence", "/map/reference_path"):
        assert full_recording[path].static, path
    assert _in_run(full_recording["/map/reference"].sim_times_s)


def test_sonar_sweeps_of_every_robot_are_recorded(
    full_recording: dict[str, EntityData],
) -> None:
    for name in ROBOTS:
        sweeps = full_recording[f"/map/robots/{name}/sonar"].values("LineStrips2D:strips")
        assert _in_run([t for t, _ in sweeps]), name
        assert len(sweeps) >= 0.9 * 20 * DURATION_S  # one sweep per telemetry message
        heard = [rays for _, rays in sweeps if rays]
        assert heard, f"{name} never heard an echo (the robots are within sonar range)"
        assert all(len(ray) == 2 for rays in heard for ray in rays)  # estimate -> echo


def test_recording_cut_by_sigkill_stays_readable(recorded_run: RecordedRun) -> None:
    with pytest.warns(RerunWarning, match="no footer"):
        cut = read_recording(recorded_run.cut)
    times = cut["/map/robots/robot1"].sim_times_s
    assert _in_run(times) and max(times) > 0.5
    assert cut["/errors/formation"].sim_times_s


def test_restarted_dashboard_keeps_the_old_file_and_resumes(recorded_run: RecordedRun) -> None:
    assert f"previous recording kept as {recorded_run.cut}" in recorded_run.restart_output
    with pytest.warns(RerunWarning, match="no footer"):
        cut_end_s = max(read_recording(recorded_run.cut)["/map/robots/robot1"].sim_times_s)
    resumed = read_recording(recorded_run.resumed)
    times = resumed["/map/robots/robot1"].sim_times_s
    assert _in_run(times)
    assert max(times) >= DURATION_S - 0.1 and max(times) > cut_end_s


def test_listening_dashboards_leave_the_swarm_unchanged(recorded_run: RecordedRun) -> None:
    watched = (recorded_run.swarm_dir / "summary.json").read_bytes()
    alone = (recorded_run.reference_dir / "summary.json").read_bytes()
    assert json.loads(watched)["duration_s"] == pytest.approx(DURATION_S)
    assert watched == alone


def test_replay_serves_a_recording_to_the_web_viewer(
    recorded_run: RecordedRun, tmp_path: Path
) -> None:
    web_port, grpc_port = free_port(), free_port()
    argv = ["-m", "services.dashboard", "replay", str(recorded_run.full)]
    ports = ["--web-port", str(web_port), "--grpc-port", str(grpc_port)]
    replay = start("replay", [*argv, *ports], tmp_path)
    try:
        url = replay.wait_for_line("open ").removeprefix("open ").strip()
        assert url == (
            f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"
        )

        def page_served() -> bool:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=2) as r:
                    return r.status == 200 and b"<html" in r.read().lower()
            except OSError:
                return False

        wait_for(page_served, 30, 0.2, describe="the replay's web viewer")
        assert "Listening for gRPC connections" in replay.output()
    finally:
        assert replay.stop() == 0
    with pytest.raises(OSError):  # the server went with it
        socket.create_connection(("127.0.0.1", grpc_port), timeout=2).close()

"""A robot process whose world held its time (world/realtime_guard.py) past the robot's sense
time-out: the robot stopped safely meanwhile, its fabric running on the extrapolated time.
When sense messages come back at the world's own, earlier time, the fabric runs on from where
it is instead of standing still (no sonar measurement, no timer) until the world catches up.
The process's own loop body on a fake monotonic clock, as in tests/test_firmware.py."""

from __future__ import annotations

import itertools

import pytest

from robot_firmware.net.wire import SenseMessage, encode_sense
from robot_firmware.tick_scheduler import RunTick, SafeStop
from tests.fuzz.processes import Robot, make_robot, robot_credentials

MS = 1_000_000


@pytest.fixture(scope="module")
def _robot_credentials(tmp_path_factory: pytest.TempPathFactory) -> None:
    robot_credentials(tmp_path_factory.mktemp("credentials"))


def _period(robot: Robot, now_ms: int, world_t_ms: int | None) -> RunTick | SafeStop | None:
    process = robot.process
    if world_t_ms is not None:
        message = SenseMessage(
            encoder_counts=(0, 0, 0, 0),
            sonar_echo_times_s=(None,) * process.mission.sonar_count,
            fix=None,
            tick=world_t_ms // 10,
            t_ns=world_t_ms * MS,
        )
        process._sense.append((encode_sense(message), now_ms * MS))
    process._take_sense()
    decision = process.scheduler.poll(now_ms * MS, 0)
    if isinstance(decision, RunTick | SafeStop):
        process._run_period(decision, robot.act, robot.radio, robot.telemetry)
        process.scheduler.finished(decision, now_ms * MS)
        return decision
    return None


@pytest.mark.usefixtures("_robot_credentials")
def test_after_a_held_world_the_fabric_runs_on_instead_of_waiting_for_the_world() -> None:
    robot = make_robot("robot2")
    fabric = robot.process.fabric
    for now_ms in range(0, 200, 10):  # the world at 1 s, in step with the wall clock
        _period(robot, now_ms, 1_000 + now_ms)
    for now_ms in range(200, 500, 10):  # 300 ms of wall time, no sense message reaches it
        _period(robot, now_ms, None)
    assert robot.process.scheduler.safe_stopped
    stopped_at_ns = fabric.now_ns
    resumed_fabric_ns = []
    for now_ms in range(500, 600, 10):  # back, at the world's held time: 1.19 s and on
        decision = _period(robot, now_ms, 1_190 + (now_ms - 500))
        assert isinstance(decision, RunTick)
        resumed_fabric_ns.append(fabric.now_ns)
    steps_ms = [(b - a) / MS for a, b in itertools.pairwise(resumed_fabric_ns)]
    print(
        f"\nfabric after the resume: {(resumed_fabric_ns[0] - stopped_at_ns) / MS:.0f} ms on, "
        f"then steps of {steps_ms} ms"
    )
    assert resumed_fabric_ns[0] >= stopped_at_ns
    assert steps_ms == [10.0] * len(steps_ms)

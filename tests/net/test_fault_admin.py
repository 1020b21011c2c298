"""A robot's `fault` admin verb, through the dispatcher its main loop uses, on a real robot
process built without a network: a register fault lands in the FPGA model and shows in the act
messages and the telemetry; bad input is refused with a reason and changes nothing."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest

import robot_firmware.runtime as runtime_module
from robot_firmware.net.admin import AdminCounters, answer
from robot_firmware.net.messages import AdminError, AdminRefusal, RegisterFaultsReply
from robot_firmware.net.wire import ActMessage, decode_act
from tests.fuzz.processes import Robot, make_robot, robot_credentials

PERIOD_NS = 10_000_000


@pytest.fixture(scope="module", autouse=True)
def _robots_have_credentials(tmp_path_factory: pytest.TempPathFactory) -> None:
    robot_credentials(tmp_path_factory.mktemp("credentials"))


@pytest.fixture
def robot() -> Iterator[Robot]:
    yield make_robot("robot2")


def ask(robot: Robot, body: object, counters: AdminCounters | None = None) -> Any:
    payload = body if isinstance(body, bytes) else json.dumps(body).encode()
    return answer(robot.process.admin_handlers(), "fault", payload, counters)


def tick(robot: Robot) -> ActMessage:
    robot.control_tick((robot.ticks + 1) * PERIOD_NS)
    act = decode_act(robot.act.payloads[-1])
    assert act is not None
    return act


def state(robot: Robot) -> object:
    fabric = robot.process.fabric
    return (
        fabric.faults.active,
        fabric.faults.tick_extra_s,
        fabric.bus.snapshot(),
        fabric.hw_read_actuation(),
    )


def test_an_empty_body_lists_the_active_faults(robot: Robot) -> None:
    assert ask(robot, b"") == RegisterFaultsReply(robot="robot2", active=())
    ask(robot, {"fault": "fix_cut", "robot": "robot2"})
    listed = ask(robot, b"")
    assert isinstance(listed, RegisterFaultsReply)
    assert [f.fault for f in listed.active] == ["fix_cut"]


def test_a_stuck_pwm_shows_in_the_act_messages_and_the_telemetry(robot: Robot) -> None:
    tick(robot)
    reply = ask(robot, {"fault": "pwm_stuck", "robot": "robot2", "wheel": 1, "duty": -0.4})
    assert isinstance(reply, RegisterFaultsReply)
    assert [(f.fault, getattr(f, "duty", None)) for f in reply.active] == [("pwm_stuck", -0.4)]
    act = tick(robot)
    assert act.duty == (0.0, -0.4, 0.0, 0.0)
    assert act.enabled[1]
    telemetry = robot.process.telemetry(robot.ticks * PERIOD_NS)
    assert telemetry.register_faults == ("pwm_stuck(wheel=1, duty=-0.4)",)
    ask(robot, {"fault": "clear_registers", "robot": "robot2"})
    assert tick(robot).duty == (0.0, 0.0, 0.0, 0.0)  # unlocalised: the firmware drives nothing
    assert robot.process.telemetry(robot.ticks * PERIOD_NS).register_faults == ()


def test_a_forced_expiry_cuts_one_act_message_and_the_next_tick_re_arms(robot: Robot) -> None:
    assert not tick(robot).watchdog_expired
    ask(robot, {"fault": "watchdog_expire", "robot": "robot2"})
    cut = tick(robot)
    assert cut.watchdog_expired and cut.enabled == (False,) * 4
    assert robot.process.fabric.faults.active == ()
    assert not tick(robot).watchdog_expired


def test_a_slow_tick_sleeps_inside_every_control_tick(
    robot: Robot, monkeypatch: pytest.MonkeyPatch
) -> None:
    slept: list[float] = []
    monkeypatch.setattr(runtime_module.time, "sleep", slept.append)
    tick(robot)
    assert slept == []
    ask(robot, {"fault": "tick_slow", "robot": "robot2", "extra_ms": 25})
    tick(robot)
    tick(robot)
    assert slept == [pytest.approx(0.025)] * 2
    ask(robot, {"fault": "clear_registers", "robot": "robot2"})
    tick(robot)
    assert len(slept) == 2


REFUSED: list[tuple[bytes, str, str]] = [
    (b"{not json", AdminRefusal.NOT_JSON, "fault refused"),
    (b'{"fault": "encoder_melted", "robot": "robot2"}', AdminRefusal.INVALID_REQUEST, "fault"),
    (b'{"fault": "encoder_stuck", "robot": "robot2"}', AdminRefusal.INVALID_REQUEST, "wheel"),
    (
        b'{"fault": "encoder_stuck", "robot": "robot2", "wheel": 4}',
        AdminRefusal.INVALID_REQUEST,
        "wheel",
    ),
    (
        b'{"fault": "pwm_stuck", "robot": "robot2", "wheel": 0, "duty": 1.5}',
        AdminRefusal.INVALID_REQUEST,
        "duty",
    ),
    (
        b'{"fault": "tick_slow", "robot": "robot2", "extra_ms": 5, "cpu": 1}',
        AdminRefusal.INVALID_REQUEST,
        "cpu",
    ),
    (b'{"fault": "fix_cut", "robot": "robot1"}', AdminRefusal.UNKNOWN_ROBOT, "'robot1'"),
    (b'{"fault": "kill", "process": "robot2"}', AdminRefusal.INVALID_REQUEST, "process fault"),
    (b'{"fault": "partition", "robots": ["robot2"]}', AdminRefusal.INVALID_REQUEST, "network"),
    (b"[]", AdminRefusal.INVALID_REQUEST, "fault refused"),
]


@pytest.mark.parametrize(("body", "reason", "names"), REFUSED)
def test_bad_input_is_refused_with_a_reason_and_changes_nothing(
    robot: Robot, body: bytes, reason: str, names: str
) -> None:
    ask(robot, {"fault": "encoder_stuck", "robot": "robot2", "wheel": 3})
    tick(robot)
    before = state(robot)
    counters = AdminCounters()
    reply = ask(robot, body, counters)
    assert isinstance(reply, AdminError), reply
    assert reply.reason == reason
    assert names in reply.error
    assert counters.refused == {reason: 1}
    assert state(robot) == before

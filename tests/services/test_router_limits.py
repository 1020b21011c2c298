"""The router's size limits (services/router/access.py, "Sizes") against what a run sends: the
largest message a robot can make on each limited key fits its limit, and the limits are in
the config the router runs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from pydantic import TypeAdapter

from robot_firmware.net.admin import answer
from robot_firmware.net.frames import FRAME_BYTES, DropReason
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.wire import ActMessage, WireDropReason, encode_act
from services.router.access import (
    ACT_AND_FRAME_BYTES_MAX,
    MESSAGE_BYTES_MAX,
    TELEMETRY_BYTES_MAX,
    router_config_document,
)
from swarm_config.credentials import generate_credential_set
from swarm_config.faults import RegisterFault
from tests.fuzz.processes import Robot, make_robot, robot_credentials

KEYS = SwarmKeys("lab")
LONGEST_NAME = "r" * 32
"""Robot names are at most 32 characters (robot_firmware/net/keys.py)."""
BIGGEST_INT = 2**63 - 1
LONGEST_FLOAT = -1.2345678901234567e-300
WHEELS = 4


@pytest.fixture
def robot(tmp_path_factory: pytest.TempPathFactory) -> Robot:
    """robot2's process, booted, without a network (the credentials it needs are made once)."""
    robot_credentials(tmp_path_factory.mktemp("credentials"))
    return make_robot("robot2")


def every_register_fault(robot: str) -> list[dict[str, Any]]:
    """One fault of every key the fault table keeps apart (robot_firmware/fpga/faults.py)."""
    faults: list[dict[str, Any]] = [
        {"fault": kind} for kind in ("sonar_no_echo", "fix_cut", "watchdog_expire")
    ]
    faults.append({"fault": "tick_slow", "extra_ms": 9999.123456789012})
    for wheel in range(WHEELS):
        faults.append({"fault": "encoder_stuck", "wheel": wheel})
        faults.append({"fault": "pwm_stuck", "wheel": wheel, "duty": -0.12345678901234567})
        faults += [
            {"fault": "encoder_bit_stuck", "wheel": wheel, "bit": bit, "value": 1}
            for bit in range(32)
        ]
    return [{**fault, "robot": robot} for fault in faults]


def widest(value: Any) -> Any:
    """`value` with every number and name as long as its JSON can get."""
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, int):
        return BIGGEST_INT
    if isinstance(value, float):
        return LONGEST_FLOAT
    if isinstance(value, dict):
        return {key: widest(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [widest(item) for item in value]
    return value


def test_the_run_router_config_holds_the_limits() -> None:
    credentials = generate_credential_set("lab", ("robot1", "robot2"))
    document = router_config_document(credentials, Path("users.txt"), ["tcp/127.0.0.1:7447"])
    assert document["transport"]["link"]["rx"]["max_message_size"] == MESSAGE_BYTES_MAX
    limits = {
        key: entry["size_limit"]
        for entry in document["low_pass_filter"]
        for key in entry["key_exprs"]
        if entry["flows"] == ["ingress"] and "put" in entry["messages"]
    }
    assert limits == {
        KEYS.act_all: ACT_AND_FRAME_BYTES_MAX,
        KEYS.radio_tx_all: ACT_AND_FRAME_BYTES_MAX,
        KEYS.telemetry_all: TELEMETRY_BYTES_MAX,
    }
    assert max(limits.values()) <= MESSAGE_BYTES_MAX


def test_an_act_message_and_a_frame_fit_their_limit() -> None:
    act = ActMessage(
        tick=BIGGEST_INT,
        duty=(LONGEST_FLOAT,) * 4,
        enabled=(True,) * 4,
        watchdog_expired=True,
        radio_frames=255,
    )
    assert len(encode_act(act)) <= ACT_AND_FRAME_BYTES_MAX
    assert FRAME_BYTES <= ACT_AND_FRAME_BYTES_MAX


def test_the_widest_telemetry_sample_fits_its_limit(robot: Robot) -> None:
    """A real robot's telemetry after a tick, with every register fault in force, every drop
    counter present, every number at its longest, the longest names, twelve sonar gaps and
    echoes and ten recent misses: still well inside the limit."""
    robot.control_tick(10_000_000)
    adapter: TypeAdapter[RegisterFault] = TypeAdapter(RegisterFault)
    for fault in every_register_fault("robot2"):
        robot.process.fabric.faults.apply(adapter.validate_python(fault))
    sample = robot.process.telemetry(20_000_000).model_dump(mode="json")
    assert len(sample["register_faults"]) == 3 + 1 + WHEELS * (2 + 32)
    sample |= {
        "robot": LONGEST_NAME,
        "leader": LONGEST_NAME,
        "frames": {"accepted": 0} | {reason.value: 0 for reason in DropReason},
        "dropped_sense": {reason.value: 0 for reason in WireDropReason},
        "sonar_range_m": [0.0] * 12,
        "sonar_echoes_m": [[0.0, 0.0]] * 12,
    }
    sample["timing"]["recent_miss_ticks"] = [0] * 10
    sample["timing"]["period_jitter_p99_ms"] = 0.0
    size = len(json.dumps(widest(sample)).encode())
    print(f"\nthe widest telemetry sample: {size} bytes (limit {TELEMETRY_BYTES_MAX})")
    assert size <= TELEMETRY_BYTES_MAX // 4


def test_a_register_dump_fits_the_router_message_limit(robot: Robot) -> None:
    reply = answer(robot.process.admin_handlers(), "regs", b"")
    size = len(reply.model_dump_json().encode())
    assert 1_000 < size <= MESSAGE_BYTES_MAX // 16

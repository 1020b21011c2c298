"""Real robot and world processes for the fuzz tests, without a network.

`RobotProcess` and `WorldProcess` open their Zenoh session only in `run`, so a test can build
them and call the same methods their main loops call: `_take_sense` (sense messages to the
pins), `_control` (one 5C tick, with publishers that only keep what is put), `_drain` (act
messages to the world's duty table) and the admin handlers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robot_firmware.runtime import RobotConfig, RobotProcess
from swarm_config.scenario import load_scenario
from world.runtime import WorldConfig, WorldProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


@dataclass
class KeptPublisher:
    """Stands in for a zenoh.Publisher: keeps every payload put."""

    payloads: list[bytes] = field(default_factory=list)

    def put(self, payload: bytes) -> None:
        self.payloads.append(bytes(payload))


@dataclass
class Robot:
    """A booted robot process and what its main loop would have published."""

    process: RobotProcess
    act: KeptPublisher = field(default_factory=KeptPublisher)
    radio: KeptPublisher = field(default_factory=KeptPublisher)
    telemetry: KeptPublisher = field(default_factory=KeptPublisher)
    ticks: int = 0

    def sense(self, payload: bytes) -> None:
        """One sense message through the robot's own path to its pins."""
        self.process._sense.append((payload, 0))
        self.process._take_sense()

    def control_tick(self, now_ns: int) -> None:
        self.process._control(now_ns, self.ticks, self.act, self.radio, self.telemetry)
        self.ticks += 1

    def registers(self) -> list[int]:
        """Every register's stored bits, in address order (no side effects)."""
        bus = self.process.fabric.bus
        return [
            peripheral.peek(reg.offset)
            for _, peripheral in bus.mapped()
            for reg in peripheral.registers
        ]

    def wheel_commands(self) -> np.ndarray:
        report = self.process.last_report
        assert report is not None
        return np.asarray(report.outputs.wheel_speed_radps, dtype=np.float64)


_CREDENTIALS: dict[str, Path] = {}


def robot_credentials(directory: Path) -> None:
    """Write a fresh credential set for the paper scenario's robots into `directory` (once per
    session), for robot configurations that need one."""
    if _CREDENTIALS or "credentials" not in RobotConfig.model_fields:
        return
    from swarm_config.credentials import generate_credential_set, write_credential_set

    names = load_scenario(PAPER).robot_names
    _CREDENTIALS.update(write_credential_set(directory, generate_credential_set("lab", names)))


def make_robot(name: str = "robot2") -> Robot:
    given: dict[str, object] = {"name": name, "scenario": PAPER}
    if name in _CREDENTIALS:
        given["credentials"] = _CREDENTIALS[name]
    process = RobotProcess(RobotConfig.model_validate(given))
    process.firmware.boot(process._tick_fabric)
    return Robot(process)


def assert_same_actuation(fed_everything: Robot, fed_valid_only: Robot) -> None:
    """The two robots' pins and the last tick's commands are identical."""
    a, b = fed_everything, fed_valid_only
    assert a.act.payloads[-1] == b.act.payloads[-1], "the act messages differ"
    assert a.process.fabric.hw_read_actuation() == b.process.fabric.hw_read_actuation()
    assert a.registers() == b.registers(), "the register files differ"
    assert np.array_equal(a.wheel_commands(), b.wheel_commands(), equal_nan=True)
    assert a.radio.payloads == b.radio.payloads


def make_world() -> WorldProcess:
    scenario = load_scenario(PAPER)
    return WorldProcess(WorldConfig(scenario=PAPER), scenario)

"""Every robot as real firmware on a real fabric model, with the world, in one process.

Each robot gets its own `Fabric` (register model and bus), `Drivers` and `Firmware`; the
`WorldEngine` plays physics, sensors and radio.  Per control period: the world's sense
messages go onto each fabric's pins, frames that have arrived are handed to their receivers,
every firmware runs its 5C tick (frames it broadcasts go to the radio medium), the PWM pins are
read back, and the world and the fabrics advance by one period (fabrics in `fabric_step_ns`
slices so sonar echoes and the watchdog see time pass).  No network is involved: this is the
closed loop of the networked swarm without Zenoh, used to check the firmware against the batch
simulator: the world engine takes the batch simulator's world step (`world.step`), so from the
same seed both see the same fix, sonar and wheel-slip noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robot_firmware.drivers import Drivers
from robot_firmware.firmware import Firmware, RobotMission, TickReport
from robot_firmware.fpga.fabric import Fabric, FabricConfig
from robot_firmware.pins import apply_sense
from swarm_config.scenario import Scenario, load_rule_base
from world.engine import NS_PER_S, WorldEngine


@dataclass
class FirmwareRobot:
    fabric: Fabric
    drivers: Drivers
    firmware: Firmware


class FirmwareSwarm:
    """A scenario's robots running their firmware against the world engine, in lockstep."""

    def __init__(
        self,
        scenario: Scenario,
        key: bytes,
        fabric_step_ns: int = 1_000_000,
        seed: int | None = None,
    ) -> None:
        self.scenario = scenario
        self.world = WorldEngine(scenario, seed=seed)
        self.period_ns = round(scenario.controller_params().control_period_s * NS_PER_S)
        if self.period_ns % fabric_step_ns:
            raise ValueError("the control period must be a whole number of fabric steps")
        self.fabric_step_ns = fabric_step_ns
        rule_base = load_rule_base(scenario)
        sonar_count = len(scenario.controller_params().sonar_beam_angles_rad)
        self.robots: list[FirmwareRobot] = []
        for name in scenario.robot_names:
            fabric = Fabric(FabricConfig(n_sonar=sonar_count))
            drivers = Drivers.attach(fabric.bus, sonar_count)
            firmware = Firmware(RobotMission.from_scenario(scenario, name, rule_base), drivers, key)
            firmware.boot(fabric.tick)
            self.robots.append(FirmwareRobot(fabric, drivers, firmware))
        self.last_reports: list[TickReport] = []

    def step(self) -> None:
        """One control period of the whole swarm."""
        world = self.world
        now_ns = world.t_ns
        for robot, sense in zip(self.robots, world.sense(), strict=True):
            apply_sense(robot.fabric, sense)
        for receiver, _sender, payload in world.due_frames():
            self.robots[receiver].firmware.receive(payload, now_ns)
        reports = []
        for index, robot in enumerate(self.robots):
            report = robot.firmware.control_tick(now_ns)
            if report.frame is not None:
                world.transmit(index, report.frame)
            reports.append(report)
        self.last_reports = reports
        duty = np.array([robot.fabric.hw_read_actuation().duty for robot in self.robots])
        world.advance(duty, self.period_ns)
        for robot in self.robots:
            robot.fabric.advance(self.period_ns, self.fabric_step_ns)

    def run(self, duration_s: float | None = None) -> dict[str, object]:
        ticks = round((duration_s or self.scenario.duration_s) * NS_PER_S / self.period_ns)
        for _ in range(ticks):
            self.step()
        return self.world.summary()

"""The firmware on the fabric model, closed through the world engine, in one process."""

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerState,
    RobotRole,
    control_step,
)
from robot_firmware.control.estimation import EstimatorState
from robot_firmware.control.pid import PidState
from robot_firmware.drivers import Drivers
from robot_firmware.firmware import Firmware, RobotMission
from robot_firmware.fpga.fabric import Fabric, FabricConfig
from robot_firmware.net.frames import key_from_secret
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.scenario import load_rule_base, load_scenario
from world.metrics import FormationLayout

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
KEY = key_from_secret("test swarm secret")


def _stack(items: list, axis_shape: tuple[int, ...] = (1,)):  # type: ignore[no-untyped-def]
    """Stack per-robot dataclasses of arrays into one batch of shape (1, N, ...)."""
    first = items[0]
    values = {}
    for f in fields(first):
        parts = [getattr(item, f.name) for item in items]
        if isinstance(parts[0], (EstimatorState, PidState)):
            values[f.name] = _stack(parts, axis_shape)
        elif isinstance(parts[0], (bool, float, int)) and not isinstance(parts[0], np.ndarray):
            values[f.name] = parts[0]
        else:
            values[f.name] = np.stack([np.asarray(p) for p in parts])[None]
    return type(first)(**values)


@pytest.mark.slow
def test_firmware_closed_loop_tracks_the_papers_circle() -> None:
    scenario = load_scenario(PAPER)
    swarm = FirmwareSwarm(scenario, KEY)
    summary = swarm.run(scenario.duration_s)
    assert summary["leader_tracking_rms_m"] <= 0.02
    for value in summary["formation_rms_m"].values():  # type: ignore[union-attr]
        assert value <= 0.03
    assert summary["collisions"] == 0
    for robot in swarm.robots:
        assert robot.firmware.decoder.counters.accepted > 0
        assert robot.firmware.decoder.counters.dropped_total == 0
        assert robot.drivers.bus_errors == 0


def test_firmware_and_batch_simulator_compute_the_same_wheel_commands() -> None:
    scenario = load_scenario(PAPER)
    swarm = FirmwareSwarm(scenario, KEY)
    for _ in range(150):  # past boot, localisation and the first radio frames
        swarm.step()
    states = [r.firmware.last_state for r in swarm.robots]
    inputs = [r.firmware.last_inputs for r in swarm.robots]
    assert all(s is not None for s in states) and all(i is not None for i in inputs)
    batch_state: ControllerState = _stack(states)  # type: ignore[arg-type]
    batch_inputs: ControlInputs = _stack(inputs)  # type: ignore[arg-type]
    layout = FormationLayout.from_scenario(scenario)
    n = len(layout.names)
    # Exactly how the batch simulator lays out roles and schedulers for B = 1 run of N robots.
    role = RobotRole(
        is_leader=(np.arange(n) == layout.leader_index)[None],
        slot_distance_m=layout.slot_distance_m,
        slot_angle_rad=layout.slot_angle_rad,
    )
    rules = load_rule_base(scenario).expand_dims((0, 1, 2))
    _, batch_out = control_step(
        batch_state, batch_inputs, role, rules, scenario.controller_params()
    )
    firmware_wheels = np.stack([r.outputs.wheel_speed_radps for r in swarm.last_reports])
    assert np.any(firmware_wheels != 0.0)
    np.testing.assert_array_equal(batch_out.wheel_speed_radps[0], firmware_wheels)


def test_watchdog_cuts_the_motors_when_the_loop_stops() -> None:
    scenario = load_scenario(PAPER)
    rule_base = load_rule_base(scenario)
    fabric = Fabric(FabricConfig(n_sonar=12))
    drivers = Drivers.attach(fabric.bus, 12)
    firmware = Firmware(RobotMission.from_scenario(scenario, "robot2", rule_base), drivers, KEY)
    firmware.boot(fabric.tick)
    drivers.motors.set_duty((0.5, -0.5, 0.5, -0.5))
    drivers.watchdog.kick()
    timeout_ns = firmware.mission.watchdog_timeout_ms * 1_000_000
    step_ns = 1_000_000
    elapsed = 0
    while elapsed < timeout_ns - step_ns:
        fabric.tick(step_ns)
        elapsed += step_ns
        assert any(d != 0.0 for d in fabric.hw_read_actuation().duty), elapsed
    for _ in range(2):
        fabric.tick(step_ns)
    actuation = fabric.hw_read_actuation()
    assert actuation.watchdog_expired
    assert actuation.duty == (0.0, 0.0, 0.0, 0.0)


@pytest.mark.slow
def test_reported_sonar_echoes_lie_on_the_surfaces_the_sonar_heard() -> None:
    """The echo points the firmware reports (telemetry, dashboard rays) are on real surfaces.

    An echo is placed on its transducer's beam axis at the measured gap from the rim, seen from
    the estimated pose. One that came from the edge of the +-15 deg cone is then up to
    2 sin(7.5 deg) times its reach from where it was heard; 5 cm more covers the motion of both
    robots in the 50 ms between sweeps, the sonar noise and the pose estimate's error.
    """
    scenario = load_scenario(PAPER)
    swarm = FirmwareSwarm(scenario, KEY)
    centres, radii = scenario.obstacle_arrays()
    params = scenario.controller_params()
    half_chord = 2.0 * np.sin(scenario.sensors.sonar.beam_half_width_rad / 2.0)
    off_surface_m: list[float] = []
    allowed_m: list[float] = []
    for step in range(2000):
        swarm.step()
        if step < 300 or step % 5:
            continue  # skip the start-up, sample every 50 ms
        poses = swarm.world.bodies.pose
        for i, robot in enumerate(swarm.robots):
            gaps = robot.firmware.sonar_gap_m
            points = robot.firmware.sonar_echo_points_m()
            assert len(points) == int(np.sum(np.isfinite(gaps)))
            for (x, y), gap in zip(points, gaps[np.isfinite(gaps)], strict=True):
                to_obstacles = np.abs(np.hypot(*(centres - (x, y)).T) - radii)
                peers = np.delete(poses, i, axis=0)[:, :2]
                to_peers = np.abs(np.hypot(*(peers - (x, y)).T) - params.body_radius_m)
                off_surface_m.append(float(min(to_obstacles.min(), to_peers.min())))
                allowed_m.append(half_chord * (params.body_radius_m + float(gap)) + 0.05)
    off = np.array(off_surface_m)
    assert off.size > 500, "the robots should hear the obstacle and each other"
    assert np.all(off <= np.array(allowed_m)), np.max(off - np.array(allowed_m))
    assert np.mean(off < 0.02) > 0.5  # most echoes come from near the beam axis

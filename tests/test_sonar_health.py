"""A deaf sonar ring is found out by the peers it should hear, and the robot holds still while it
is deaf (robot_firmware/sonar_health.py, robot_firmware/firmware.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from robot_firmware.sonar_health import SonarHealth
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.faults import SonarNoEchoFault
from swarm_config.scenario import load_scenario
from tests.test_firmware import KEY, PAPER

SILENT = np.full(12, np.inf)
HEARD = np.where(np.arange(12) == 3, 0.8, np.inf)


def test_silence_is_a_failure_only_against_a_peer_in_reach() -> None:
    health = SonarHealth.for_range(3.0)
    assert health.reach_m == 2.5
    for _ in range(10):
        assert not health.sweep(SILENT, [2.6, 7.0])  # open space: no evidence either way
    assert not health.sweep(SILENT, [0.4])
    assert not health.sweep(SILENT, [0.4])
    assert health.sweep(SILENT, [0.4])  # the third silent sweep with a peer 0.4 m away
    assert health.failures == 1
    assert health.sweep(SILENT, [])  # no evidence keeps the verdict
    assert not health.sweep(HEARD, [0.4])  # any echo: well again
    assert health.silent_sweeps == 0


def test_an_echo_in_between_starts_the_count_again() -> None:
    health = SonarHealth.for_range(3.0)
    for ranges in (SILENT, SILENT, HEARD, SILENT, SILENT):
        assert not health.sweep(ranges, [1.0])
    assert health.sweep(SILENT, [1.0]) and health.failures == 1


def test_a_leader_whose_sonar_goes_deaf_holds_still_and_drives_on_when_it_hears_again() -> None:
    # Deaf from 2 s to 10 s, across the leader's first pass of the obstacle (about 6.6 s),
    # where it touched the obstacle before it held still.
    scenario = load_scenario(Path(PAPER))
    swarm = FirmwareSwarm(scenario, KEY)
    leader = swarm.robots[0]
    deaf_from, deaf_to, end = 200, 1000, 1600
    held_from: int | None = None
    moved_while_held_m = 0.0
    off_track_m: list[float] = []
    for k in range(end):
        if k == deaf_from:
            leader.fabric.faults.apply(SonarNoEchoFault(fault="sonar_no_echo", robot="robot1"))
        if k == deaf_to:
            leader.fabric.faults.clear()
        before = swarm.world.bodies.pose[0, :2].copy()
        swarm.step()
        failed = leader.firmware.sonar_health.failed
        if failed and held_from is None:
            held_from = k
        if held_from is not None and held_from + 30 <= k < deaf_to:
            assert failed
            assert leader.fabric.hw_read_actuation().duty == (0.0, 0.0, 0.0, 0.0)
            moved_while_held_m += math.dist(before, swarm.world.bodies.pose[0, :2])
        if k >= deaf_to:
            reference, _ = leader.firmware.mission.trajectory.evaluate(swarm.world.t_s)
            off_track_m.append(math.dist(swarm.world.bodies.pose[0, :2], reference[:2]))
    summary = swarm.world.summary()
    assert held_from is not None
    print(
        f"\nrobot1's sonar deaf at t = {deaf_from / 100:.2f} s, taken as failed at "
        f"{held_from / 100:.2f} s; moved {moved_while_held_m * 100:.2f} cm while held; "
        f"collisions {summary['collisions']}, obstacle clearance "
        f"{summary['min_obstacle_clearance_m']} m"
    )
    assert held_from - deaf_from <= 25  # three sweeps at 20 Hz, and the one under way
    assert moved_while_held_m < 0.01
    assert not leader.firmware.sonar_health.failed
    assert leader.firmware.sonar_health.failures == 1
    assert summary["collisions"] == 0
    # It drives on, closing on its trajectory as a new leader does (at 0.15 m/s: in the 6 s
    # after, at least 0.7 m of the way the trajectory went on while it held still).
    print(
        f"off its trajectory: {off_track_m[0]:.2f} m when it hears again, "
        f"{off_track_m[-1]:.2f} m 6 s later"
    )
    assert off_track_m[0] - off_track_m[-1] > 0.7

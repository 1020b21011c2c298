"""Cost of the robot firmware's control tick (not a test: prints a table).

Runs the paper scenario with every robot as firmware on its fabric model (no network), and
measures the wall time of `Firmware.control_tick` alone, the fabric's time per control period,
and the bus accesses (reads and writes) the firmware makes per tick.  Median over repetitions;
machine and date printed with the table.

    .venv/bin/python bench/firmware_tick.py [--ticks 1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from machine import machine_lines

from robot_firmware.net.frames import key_from_secret
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _measure(ticks: int) -> dict[str, float]:
    scenario = load_scenario(ROOT / "configs/scenarios/paper.yaml")
    swarm = FirmwareSwarm(scenario, key_from_secret("bench"))
    for _ in range(50):  # boot, localise, first frames
        swarm.step()
    robot = swarm.robots[0]
    bus = robot.fabric.bus
    firmware = robot.firmware
    tick_s: list[float] = []
    original = firmware.control_tick

    def timed(now_ns: int):  # type: ignore[no-untyped-def]
        start = time.perf_counter()
        report = original(now_ns)
        tick_s.append(time.perf_counter() - start)
        return report

    firmware.control_tick = timed  # type: ignore[method-assign]
    reads0, writes0 = bus.read_count, bus.write_count
    for _ in range(ticks):
        swarm.step()
    reads = (bus.read_count - reads0) / ticks
    writes = (bus.write_count - writes0) / ticks
    steps = swarm.period_ns // swarm.fabric_step_ns
    start = time.perf_counter()
    for _ in range(100):
        for _ in range(steps):
            robot.fabric.tick(swarm.fabric_step_ns)
    fabric_us = (time.perf_counter() - start) / 100 * 1e6
    return {
        "tick_median_us": float(np.median(tick_s)) * 1e6,
        "tick_p99_us": float(np.percentile(tick_s, 99)) * 1e6,
        "reads": reads,
        "writes": writes,
        "fabric_us": fabric_us,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = [_measure(args.ticks) for _ in range(args.repeats)]
    median = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print("# firmware control tick")
    for line in machine_lines():
        print(line)
    print(f"# paper scenario, leader robot, {args.ticks} ticks x {args.repeats} runs (median)")
    print()
    print(f"control_tick median        {median['tick_median_us']:8.1f} us")
    print(f"control_tick p99           {median['tick_p99_us']:8.1f} us")
    print(f"bus reads per tick         {median['reads']:8.1f}")
    print(f"bus writes per tick        {median['writes']:8.1f}")
    print(f"fabric model, one period   {median['fabric_us']:8.1f} us (1 ms slices)")
    print("budget at 100 Hz            10000.0 us")


if __name__ == "__main__":
    main()

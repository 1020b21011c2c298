"""Throughput of the batch simulator on the paper scenario (not a test: prints a table).

Simulated robot-seconds per wall-clock second for batch sizes B = 1, 100 and 1000, with the
compiled kernels and with the numpy oracle (tests/control/oracle.py) in the same run, side by
side with their ratio.  Each figure is the median of several repetitions, the two paths
interleaved; compile time is excluded (one short warm-up run per path and batch size).  The
machine and the date are printed with the table.

    .venv/bin/python bench/batch_throughput.py [--repeats 3] [--sim-seconds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from machine import machine_lines
from oracle_paths import PATHS, control_path

from services.sim.batch import run_batch
from swarm_config.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _wall_s(scenario: Scenario, batch: int, sim_s: float) -> float:
    start = time.perf_counter()
    run_batch(scenario, batch_size=batch, duration_s=sim_s)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sim-seconds", type=float, default=5.0)
    parser.add_argument("--scenario", type=Path, default=ROOT / "configs/scenarios/paper.yaml")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 100, 1000])
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    robots = len(scenario.robots)

    print("# batch simulator throughput: compiled kernels vs the numpy oracle")
    for line in machine_lines():
        print(line)
    print(f"# scenario: {args.scenario.name} ({robots} robots), {args.sim_seconds} s simulated,")
    print(f"# median of {args.repeats} runs per path, interleaved; 100 Hz control")
    print()
    print(f"{'B':>6} {'compiled robot-s/s':>19} {'oracle robot-s/s':>17} {'ratio':>7}")
    for batch in args.batches:
        walls: dict[str, list[float]] = {path: [] for path in PATHS}
        for path in PATHS:
            with control_path(path):
                _wall_s(scenario, batch, 0.1)  # compile / warm caches
        for _ in range(args.repeats):
            for path in PATHS:
                with control_path(path):
                    walls[path].append(_wall_s(scenario, batch, args.sim_seconds))
        rate = {
            path: batch * robots * args.sim_seconds / statistics.median(walls[path])
            for path in PATHS
        }
        print(
            f"{batch:>6} {rate['compiled']:>19.0f} {rate['oracle']:>17.0f} "
            f"{rate['compiled'] / rate['oracle']:>6.1f}x"
        )
    print()
    print("goal: at least 10000 robot-s/s at B = 100 (compiled)")


if __name__ == "__main__":
    main()

"""Throughput of the batch simulator on the paper scenario (not a test: prints a table).

Simulated robot-seconds per wall-clock second for batch sizes B = 1, 10, 100, 1000, and the
speed-up of one batched run of B candidates over a Python loop of B single runs.  Each figure
is the median of several repetitions; the machine and the date are printed with the table.

    .venv/bin/python bench/batch_throughput.py [--repeats 3] [--sim-seconds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from machine import machine_lines

from services.sim.batch import run_batch
from swarm_config.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _time_batch(scenario_path: Path, batch: int, sim_s: float, repeats: int) -> float:
    scenario = load_scenario(scenario_path)
    walls = []
    for _ in range(repeats):
        start = time.perf_counter()
        run_batch(scenario, batch_size=batch, duration_s=sim_s)
        walls.append(time.perf_counter() - start)
    return statistics.median(walls)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sim-seconds", type=float, default=5.0)
    parser.add_argument("--scenario", type=Path, default=ROOT / "configs/scenarios/paper.yaml")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 10, 100, 1000])
    parser.add_argument("--loop-candidates", type=int, default=10)
    args = parser.parse_args()
    robots = len(load_scenario(args.scenario).robots)

    print("# batch simulator throughput")
    for line in machine_lines():
        print(line)
    print(f"# scenario: {args.scenario.name} ({robots} robots), {args.sim_seconds} s simulated,")
    print(f"# median of {args.repeats} runs; 100 Hz control, exact-equivalent physics")
    print()
    print(f"{'B':>6} {'wall s':>9} {'robot-s / s':>13} {'sim-s / s per run':>19}")
    for batch in args.batches:
        wall = _time_batch(args.scenario, batch, args.sim_seconds, args.repeats)
        robot_seconds = batch * robots * args.sim_seconds
        print(
            f"{batch:>6} {wall:>9.3f} {robot_seconds / wall:>13.0f} "
            f"{args.sim_seconds / wall:>19.2f}"
        )

    n = args.loop_candidates
    batched = _time_batch(args.scenario, n, args.sim_seconds, args.repeats)
    single = _time_batch(args.scenario, 1, args.sim_seconds, args.repeats)
    print()
    print(f"per-candidate Python loop of {n} single runs: {n * single:.3f} s")
    print(f"one batched run of {n} candidates:           {batched:.3f} s")
    print(f"speed-up of the batch path:                  {n * single / batched:.1f}x")


if __name__ == "__main__":
    main()

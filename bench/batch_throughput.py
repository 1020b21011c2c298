"""Throughput of the batch simulator on the paper scenario (not a test: prints a table).

Simulated robot-seconds per wall-clock second for batch sizes B = 1, 100 and 1000: the compiled
tick loop (`services.sim.batch.run_batch`, its runs split over one thread per CPU, at most 2)
next to the same on one thread and to its numpy oracle, the tick-by-tick loop of
tests/world/oracle.py (`run_batch_oracle`, on the numpy control and body steps of
tests/control/oracle.py), in the same run, with their ratios.  Each figure is the median of
several repetitions, the two paths interleaved; compile time is excluded (one short warm-up run
per path and batch size).  Next to each wall-clock figure, the same per CPU second of this
process (`time.process_time`), which depends less on what else the machine runs.
The machine and the date are printed with the table.

    .venv/bin/python bench/batch_throughput.py [--repeats 3] [--sim-seconds 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from arguments import positive_float, positive_int  # noqa: E402
from machine import machine_lines  # noqa: E402

from services.sim.batch import BatchResult, run_batch  # noqa: E402
from swarm_config.scenario import Scenario, load_scenario  # noqa: E402
from tests.world.oracle import run_batch_oracle  # noqa: E402

PATHS: dict[str, Callable[..., BatchResult]] = {
    "compiled": run_batch,
    "one thread": partial(run_batch, threads=1),
    "oracle": run_batch_oracle,
}


def _seconds(path: str, scenario: Scenario, batch: int, sim_s: float) -> tuple[float, float]:
    """Wall-clock and CPU seconds of one run."""
    wall = time.perf_counter()
    cpu = time.process_time()
    PATHS[path](scenario, batch_size=batch, duration_s=sim_s)
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=positive_int, default=3)
    parser.add_argument("--sim-seconds", type=positive_float, default=5.0)
    parser.add_argument("--scenario", type=Path, default=ROOT / "configs/scenarios/paper.yaml")
    parser.add_argument("--batches", type=positive_int, nargs="+", default=[1, 100, 1000])
    parser.add_argument(
        "--oracle-sim-seconds",
        type=positive_float,
        default=None,
        help="simulated seconds of the oracle's runs (default: --sim-seconds)",
    )
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    robots = len(scenario.robots)
    sim_s = {
        "compiled": args.sim_seconds,
        "one thread": args.sim_seconds,
        "oracle": args.oracle_sim_seconds or args.sim_seconds,
    }

    print("# batch simulator throughput: compiled tick loop vs the numpy oracle")
    for line in machine_lines():
        print(line)
    print(
        f"# scenario: {args.scenario.name} ({robots} robots), simulated s per run: "
        f"compiled {sim_s['compiled']}, oracle {sim_s['oracle']}"
    )
    print(f"# median of {args.repeats} runs per path, interleaved; 100 Hz control")
    print()
    print(
        f"{'B':>6} {'compiled robot-s/s':>19} {'per CPU s':>10} {'one thread':>11} "
        f"{'oracle robot-s/s':>17} {'per CPU s':>10} {'ratio':>7} {'per CPU':>8} "
        f"{'threads':>8}"
    )
    for batch in args.batches:
        walls: dict[str, list[float]] = {path: [] for path in PATHS}
        cpus: dict[str, list[float]] = {path: [] for path in PATHS}
        for path in PATHS:
            _seconds(path, scenario, batch, 0.1)  # compile / warm caches
        for _ in range(args.repeats):
            for path in PATHS:
                wall, cpu = _seconds(path, scenario, batch, sim_s[path])
                walls[path].append(wall)
                cpus[path].append(cpu)
        rate = {
            path: batch * robots * sim_s[path] / statistics.median(walls[path]) for path in PATHS
        }
        per_cpu = {
            path: batch * robots * sim_s[path] / statistics.median(cpus[path]) for path in PATHS
        }
        print(
            f"{batch:>6} {rate['compiled']:>19.0f} {per_cpu['compiled']:>10.0f} "
            f"{rate['one thread']:>11.0f} {rate['oracle']:>17.0f} {per_cpu['oracle']:>10.0f} "
            f"{rate['compiled'] / rate['oracle']:>6.1f}x "
            f"{per_cpu['compiled'] / per_cpu['oracle']:>7.1f}x "
            f"{rate['compiled'] / rate['one thread']:>7.2f}x",
            flush=True,
        )
    print()
    print(
        "ratio: compiled over oracle (wall, per CPU s); threads: compiled over compiled on one "
        "thread (wall)"
    )
    print("goal: at least 10000 robot-s/s at B = 100 (compiled)")


if __name__ == "__main__":
    main()

"""Where a robot's and the world's main-thread CPU goes in a running swarm, phase by phase
(prints tables).

It generates a wedge of N robots (as `swarm scenario generate --robots N --formation wedge`
would), runs `swarm up --no-dashboard` in real time (`--lockstep`: in lockstep) with the phase
probe of bench/phase_probe/sitecustomize.py loaded into the robot and world processes, and after
`--duration` seconds reads what the probe wrote: for each phase of the robot's control loop
(sense messages to the pins, the fabric model's time, the 5C control tick, radio frames, act
and telemetry messages, the scheduler, the garbage collector's runs) the CPU per control period
and per call, median over the robots, and the same for the world per sense tick.  Figures are
thread CPU time, so they count what the phase costs this process on a shared machine (cold
caches after another process ran included), not the wall time it waited.  Compare them with
`bench/firmware_tick.py`, which times the same control tick in a tight loop, warm, and with
`bench/robot_period.py`, which times a robot's whole period without the network, warm and with
the caches evicted.

    .venv/bin/python bench/robot_phases.py [--robots 6] [--duration 30] [--lockstep] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from arguments import positive_float, positive_int
from machine import machine_lines
from swarm_up import SwarmUp

from swarm_config.generate import GenerateRequest, generate_scenario_text

PROBE_DIR = Path(__file__).resolve().parent / "phase_probe"
PERIOD_LABEL = {"robot": "control period", "world": "sense tick"}
LOCKSTEP_SPEEDUP_BOUND = 20
"""Lockstep: the fastest a measured run may go (simulated seconds per wall second)."""


def probe_clock_cost_ns(calls: int = 200_000) -> float:
    """What one read of the thread's CPU clock costs here (the probe reads it twice a call)."""
    clock = time.thread_time_ns
    started = time.perf_counter_ns()
    for _ in range(calls):
        clock()
    return (time.perf_counter_ns() - started) / calls


def run(robots: int, duration_s: float, work: Path, lockstep: bool) -> list[dict[str, Any]]:
    scenario = work / f"wedge-{robots}.yaml"
    scenario.write_text(
        generate_scenario_text(GenerateRequest(robots=robots, formation="wedge", seed=1)),
        encoding="utf-8",
    )
    records = work / "probe"
    records.mkdir()
    os.environ["SWARM_PHASE_PROBE_DIR"] = str(records)
    os.environ["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(PROBE_DIR), os.environ.get("PYTHONPATH")) if p
    )
    try:
        # The probe drops 15 s of warm-up periods; the run goes on `duration_s` beyond that
        # (in lockstep simulated time runs faster than the wall clock: the run is long enough
        # for a swarm up to LOCKSTEP_SPEEDUP_BOUND times real time, and stopped when measured).
        sim_s = (duration_s + 40) * (LOCKSTEP_SPEEDUP_BOUND if lockstep else 1)
        clock = ("--lockstep",) if lockstep else ()
        up = SwarmUp(
            work / "run", "--scenario", str(scenario), "--duration", f"{sim_s:.0f}", *clock
        )
        with up:
            deadline = time.monotonic() + 120.0 + duration_s + 4.0 * robots
            while len(list(records.glob("*.json"))) < robots + 1:
                if time.monotonic() > deadline or up.process.poll() is not None:
                    raise RuntimeError(f"the probe wrote no figures; see {up.out}/logs")
                time.sleep(0.5)
            time.sleep(duration_s)
            up.stop(timeout_s=60.0 + robots)
    finally:
        del os.environ["SWARM_PHASE_PROBE_DIR"]
    return [json.loads(path.read_text()) for path in sorted(records.glob("*.json"))]


def table(role: str, records: list[dict[str, Any]]) -> list[str]:
    mine = [r for r in records if r["role"] == role and r["periods"] > 0]
    if not mine:
        return [f"no figures from the {role}"]
    per = PERIOD_LABEL[role]
    main_us = statistics.median(r["main_thread_ns"] / r["periods"] / 1e3 for r in mine)
    lines = [
        f"{role} ({len(mine)} process{'es' if len(mine) > 1 else ''}, "
        f"median over them; {statistics.median(r['periods'] for r in mine):.0f} {per}s each)",
        f"  {'phase':38} {'us per ' + per:>22} {'calls per ' + per:>24} {'us per call':>12}",
        f"  {'main thread, all of it':38} {main_us:22.1f}",
    ]
    names = sorted(mine[0]["phases"], key=lambda n: -mine[0]["phases"][n][0])
    for name in names:
        per_period = statistics.median(r["phases"][name][0] / r["periods"] / 1e3 for r in mine)
        calls = statistics.median(r["phases"][name][1] / r["periods"] for r in mine)
        per_call = statistics.median(
            r["phases"][name][0] / max(r["phases"][name][1], 1) / 1e3 for r in mine
        )
        lines.append(f"  {name:38} {per_period:22.1f} {calls:24.2f} {per_call:12.1f}")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--robots", type=positive_int, default=6, help="robots in the wedge (default 6)"
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=30.0,
        help="measured seconds after warm-up (default 30)",
    )
    parser.add_argument("--keep", type=Path, help="keep the run's files in this new directory")
    parser.add_argument(
        "--lockstep",
        action="store_true",
        help="run the swarm in lockstep (one tick per sense message) instead of real time",
    )
    args = parser.parse_args(argv)
    if args.robots < 1 or args.duration <= 0:
        parser.error("--robots is at least 1 and --duration positive")
    if args.keep is not None and args.keep.exists():
        parser.error(f"--keep {args.keep}: it exists; name a new directory")
    clock = "lockstep" if args.lockstep else "real time"
    print(f"# phases of the main loops in a running swarm (thread CPU, {clock})")
    for line in machine_lines():
        print(line)
    print(
        f"# {args.robots}-robot wedge, {args.duration:.0f} s of wall time measured after "
        "1,500 periods of warm-up; "
        f"a probed call costs about {2 * probe_clock_cost_ns() / 1e3:.1f} us more"
    )
    print("# nested: _run_period > _control > control_tick, receive, _publish_act, ...")
    if args.keep is not None:
        args.keep.mkdir(parents=True)
        records = run(args.robots, args.duration, args.keep, args.lockstep)
    else:
        with tempfile.TemporaryDirectory(prefix="robot-phases-") as work:
            records = run(args.robots, args.duration, Path(work), args.lockstep)
    print()
    for role in ("robot", "world"):
        print("\n".join(table(role, records)))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())

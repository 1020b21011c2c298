"""Real-time scale: how many robots `swarm up` keeps in real time on this machine (prints a table).

For each N (default 3, 6, 12, 24, 36, 48) it generates a wedge of N robots
(`swarm_config.generate`, as `swarm scenario generate --robots N --formation wedge` would), runs
`swarm up --no-dashboard` in real time, waits until every robot's control loop ticks, measures for
`--duration` seconds, stops the swarm with Ctrl-C (SIGINT) and reads DIR/summary.json:

* deadline misses per robot, as a share of its control ticks, over the measured window (from
  the first summary in which every robot ticks to the end) and over the whole run (what
  `swarm up` prints, robots' start-up included); median and max over the robots;
* control-period jitter p99 per robot (max over robots), from the robots' own loop timing;
* the world's real-time factor (simulated seconds per wall second, `real_time_factor` of a
  real-time world's summary.json) over the window, and how far simulated time is behind wall
  time at the end (world lag);
* the world loop's own lag: how late its sense ticks left against their due times, p99 and max
  over the run (`world_loop` of summary.json; a hold of the starvation guard is not in it);
* CPU (% of one core, /proc) per process kind: world, robot (median, max), router, launcher;
* memory per process (MiB): RSS, and PSS (shared library pages divided among the processes
  that map them) for the robots;
* collisions and the largest formation error (`formation_max_m`) of the run.

N *holds* when every robot misses at most 1 % of its deadlines in the window and the world keeps
up (real-time factor >= 0.99).  The table ends with the largest N that holds.  A size whose
median robot misses more than 20 % stops the sweep.  Figures are the median of `--repeats` runs
(default 3 up to 6 robots, 1 above).  Every subprocess has a time-out, everything the run started
is killed at the end, and the router listens on a free 127.0.0.1 port.

    .venv/bin/python bench/scale.py [--sizes 3,6,12] [--duration 30] [--repeats R] [--json FILE]
                                    [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from arguments import non_negative_int, positive_float, positive_int
from machine import machine_lines
from proc_stats import CpuWindow, memory_mib
from swarm_up import SwarmUp

from services.real_time_hold import HOLD_MISS_SHARE, HOLD_REAL_TIME_FACTOR, holds_real_time
from swarm_config.generate import GenerateRequest, generate_scenario_text

DEFAULT_SIZES = (3, 6, 12, 24, 36, 48)
CLEAR_FAILURE_MISS_SHARE = 0.20
CHEAP_SIZE = 6
"""Up to this many robots a size is run three times by default."""


@dataclass
class RunFigures:
    """One real-time run of N robots."""

    robots: int
    startup_s: float
    """From launch until a summary.json in which every robot ticks (written every 5 s)."""
    window_s: float
    miss_share: dict[str, float]
    """Per robot: deadline misses / control ticks over the window."""
    miss_share_run: dict[str, float]
    """The same over the whole run."""
    jitter_p99_ms: dict[str, float | None]
    real_time_factor: float | None
    """Simulated / wall seconds over the window."""
    real_time_factor_run: float | None
    world_lag_s: float | None
    """Wall time minus simulated time at the end."""
    sense_late_p99_ms: float | None
    sense_late_max_ms: float | None
    """The world loop's own lag over the run (summary.json `world_loop`)."""
    cpu_percent: dict[str, float | None]
    rss_mib: dict[str, float | None]
    pss_mib: dict[str, float | None]
    collisions: int
    formation_max_m: float | None


def _timings(summary: dict[str, Any]) -> dict[str, dict[str, Any] | None]:
    timings: dict[str, dict[str, Any] | None] = summary.get("control_timing") or {}
    return timings


def _everyone_ticks(summary: dict[str, Any] | None) -> bool:
    if summary is None:
        return False
    timings = _timings(summary)
    return bool(timings) and all(t is not None and t["ticks"] > 0 for t in timings.values())


def _wall_s(summary: dict[str, Any]) -> float | None:
    """Wall seconds since the world's clock started, when this summary was written."""
    factor = summary.get("real_time_factor")
    return None if not factor else float(summary["duration_s"]) / float(factor)


def run_once(robots: int, duration_s: float, seed: int, work: Path) -> RunFigures:
    scenario = work / f"wedge-{robots}.yaml"
    scenario.write_text(
        generate_scenario_text(GenerateRequest(robots=robots, formation="wedge", seed=seed)),
        encoding="utf-8",
    )
    startup_timeout_s = 60.0 + 4.0 * robots
    # swarm up ends on its own after this even if the benchmark dies.
    bound_s = startup_timeout_s + duration_s + 60.0
    launched_s = time.monotonic()
    up = SwarmUp(work / "run", "--scenario", str(scenario), "--duration", f"{bound_s:.0f}")
    with up:
        first = up.summary()
        while not _everyone_ticks(first):
            if time.monotonic() - launched_s > startup_timeout_s:
                raise RuntimeError(f"{robots} robots did not all tick in {startup_timeout_s} s")
            if up.process.poll() is not None:
                raise RuntimeError(f"swarm up exited early; see {up.out}/logs")
            time.sleep(0.5)
            first = up.summary()
        assert first is not None
        startup_s = time.monotonic() - launched_s
        pids = up.pids()
        cpu = CpuWindow(pids)
        time.sleep(duration_s)
        cpu_percent = cpu.percent()
        memory = memory_mib(pids)
        window_s = time.monotonic() - launched_s - startup_s
        up.stop(timeout_s=60.0 + robots)
    last = up.summary()
    if last is None:
        raise RuntimeError(f"no summary.json; see {up.out}/logs")

    def share(timing: dict[str, Any] | None, before: dict[str, Any] | None) -> float:
        if timing is None:
            return 1.0
        ticks = timing["ticks"] - (before["ticks"] if before else 0)
        misses = timing["deadline_misses"] - (before["deadline_misses"] if before else 0)
        return misses / ticks if ticks > 0 else 1.0

    start, end = _timings(first), _timings(last)
    wall_first, wall_last = _wall_s(first), _wall_s(last)
    factor = None
    if wall_first is not None and wall_last is not None and wall_last > wall_first:
        factor = (float(last["duration_s"]) - float(first["duration_s"])) / (wall_last - wall_first)
    return RunFigures(
        robots=robots,
        startup_s=startup_s,
        window_s=window_s,
        miss_share={name: share(end[name], start.get(name)) for name in end},
        miss_share_run={name: share(end[name], None) for name in end},
        jitter_p99_ms={name: (t or {}).get("period_jitter_p99_ms") for name, t in end.items()},
        real_time_factor=factor,
        real_time_factor_run=last.get("real_time_factor"),
        world_lag_s=None if wall_last is None else wall_last - float(last["duration_s"]),
        sense_late_p99_ms=(last.get("world_loop") or {}).get("sense_late_p99_ms"),
        sense_late_max_ms=(last.get("world_loop") or {}).get("sense_late_max_ms"),
        cpu_percent=cpu_percent,
        rss_mib={name: rss for name, (rss, _) in memory.items()},
        pss_mib={name: pss for name, (_, pss) in memory.items()},
        collisions=int(last["collisions"]),
        formation_max_m=last.get("formation_max_m"),
    )


def _robots_of(values: dict[str, float | None]) -> list[float]:
    return [v for name, v in values.items() if name.startswith("robot") and v is not None]


def _median(values: Sequence[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return statistics.median(present) if present else None


@dataclass
class SizeFigures:
    """The median over the runs of one size of each figure."""

    robots: int
    runs: int
    startup_s: float | None
    miss_median: float | None
    miss_max: float | None
    miss_max_run: float | None
    jitter_p99_max_ms: float | None
    real_time_factor: float | None
    world_lag_s: float | None
    sense_late_p99_ms: float | None
    sense_late_max_ms: float | None
    cpu_world: float | None
    cpu_robot_median: float | None
    cpu_robot_max: float | None
    cpu_router: float | None
    cpu_launcher: float | None
    rss_world_mib: float | None
    rss_robot_median_mib: float | None
    rss_robot_max_mib: float | None
    pss_robot_median_mib: float | None
    collisions: float | None
    formation_max_m: float | None

    @property
    def holds(self) -> bool:
        return holds_real_time(self.real_time_factor, self.miss_max)

    @property
    def clearly_fails(self) -> bool:
        return self.miss_median is None or self.miss_median > CLEAR_FAILURE_MISS_SHARE


def summarise(runs: Sequence[RunFigures]) -> SizeFigures:
    def per_run(pick: Callable[[RunFigures], float | None]) -> float | None:
        return _median([pick(r) for r in runs])

    def robots(values: dict[str, float | None], reduce: Callable[[list[float]], float]) -> Any:
        picked = _robots_of(values)
        return reduce(picked) if picked else None

    return SizeFigures(
        robots=runs[0].robots,
        runs=len(runs),
        startup_s=per_run(lambda r: r.startup_s),
        miss_median=per_run(lambda r: statistics.median(r.miss_share.values())),
        miss_max=per_run(lambda r: max(r.miss_share.values())),
        miss_max_run=per_run(lambda r: max(r.miss_share_run.values())),
        jitter_p99_max_ms=per_run(lambda r: robots(r.jitter_p99_ms, max)),
        real_time_factor=per_run(lambda r: r.real_time_factor),
        world_lag_s=per_run(lambda r: r.world_lag_s),
        sense_late_p99_ms=per_run(lambda r: r.sense_late_p99_ms),
        sense_late_max_ms=per_run(lambda r: r.sense_late_max_ms),
        cpu_world=per_run(lambda r: r.cpu_percent.get("world")),
        cpu_robot_median=per_run(lambda r: robots(r.cpu_percent, statistics.median)),
        cpu_robot_max=per_run(lambda r: robots(r.cpu_percent, max)),
        cpu_router=per_run(lambda r: r.cpu_percent.get("router")),
        cpu_launcher=per_run(lambda r: r.cpu_percent.get("launcher")),
        rss_world_mib=per_run(lambda r: r.rss_mib.get("world")),
        rss_robot_median_mib=per_run(lambda r: robots(r.rss_mib, statistics.median)),
        rss_robot_max_mib=per_run(lambda r: robots(r.rss_mib, max)),
        pss_robot_median_mib=per_run(lambda r: robots(r.pss_mib, statistics.median)),
        collisions=per_run(lambda r: float(r.collisions)),
        formation_max_m=per_run(lambda r: r.formation_max_m),
    )


HEADER = (
    "| N | runs | start-up s | misses median % | misses max % | whole run max % | "
    "jitter p99 max ms | real-time factor | world lag s | world loop late p99 ms | "
    "world loop late max ms | CPU world % | CPU robot median % | "
    "CPU robot max % | CPU router % | CPU launcher % | RSS world MiB | RSS robot median MiB | "
    "RSS robot max MiB | PSS robot median MiB | collisions | formation max m | holds |"
)


def _cell(value: float | None, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def table_row(s: SizeFigures) -> str:
    cells = [
        str(s.robots),
        str(s.runs),
        _cell(s.startup_s, ".0f"),
        _cell(None if s.miss_median is None else 100 * s.miss_median, ".2f"),
        _cell(None if s.miss_max is None else 100 * s.miss_max, ".2f"),
        _cell(None if s.miss_max_run is None else 100 * s.miss_max_run, ".2f"),
        _cell(s.jitter_p99_max_ms, ".2f"),
        _cell(s.real_time_factor, ".3f"),
        _cell(s.world_lag_s, ".2f"),
        _cell(s.sense_late_p99_ms, ".2f"),
        _cell(s.sense_late_max_ms, ".1f"),
        _cell(s.cpu_world, ".0f"),
        _cell(s.cpu_robot_median, ".1f"),
        _cell(s.cpu_robot_max, ".1f"),
        _cell(s.cpu_router, ".0f"),
        _cell(s.cpu_launcher, ".1f"),
        _cell(s.rss_world_mib, ".0f"),
        _cell(s.rss_robot_median_mib, ".0f"),
        _cell(s.rss_robot_max_mib, ".0f"),
        _cell(s.pss_robot_median_mib, ".0f"),
        _cell(s.collisions, ".0f"),
        _cell(s.formation_max_m, ".2f"),
        "yes" if s.holds else "no",
    ]
    return "| " + " | ".join(cells) + " |"


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma list of robot counts") from None
    if not sizes or min(sizes) < 1:
        raise argparse.ArgumentTypeError("robot counts are at least 1")
    return sorted(set(sizes))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--sizes", type=_sizes, default=list(DEFAULT_SIZES), help="robot counts, e.g. 3,6,12"
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=30.0,
        help="measured seconds per run (default: 30)",
    )
    parser.add_argument(
        "--repeats",
        type=positive_int,
        help=f"runs per size (default: 3 up to {CHEAP_SIZE} robots, 1 above)",
    )
    parser.add_argument(
        "--seed", type=non_negative_int, default=0, help="the generated scenarios' seed"
    )
    parser.add_argument("--json", metavar="FILE", help="also write every run's figures here")
    parser.add_argument(
        "--keep", metavar="DIR", help="keep each run's scenario, logs and summary.json in DIR"
    )
    args = parser.parse_args(argv)
    print("# real-time scale: swarm up --no-dashboard, generated wedge of N robots")
    for line in machine_lines():
        print(line)
    print(
        f"# {args.duration:.0f} s measured per run once every robot ticks; holds: every robot "
        f"misses <= {100 * HOLD_MISS_SHARE:.0f} % of its deadlines and real-time factor >= "
        f"{HOLD_REAL_TIME_FACTOR}"
    )
    print()
    print(HEADER)
    print("|" + "---|" * HEADER.count(" |"))
    results: list[SizeFigures] = []
    records: list[dict[str, Any]] = []
    for robots in args.sizes:
        repeats = args.repeats or (3 if robots <= CHEAP_SIZE else 1)
        runs = []
        for k in range(repeats):
            with tempfile.TemporaryDirectory(prefix=f"scale-{robots}-") as scratch:
                work = Path(args.keep) / f"n{robots}-run{k + 1}" if args.keep else Path(scratch)
                work.mkdir(parents=True, exist_ok=True)
                try:
                    runs.append(run_once(robots, args.duration, args.seed + k, work))
                except RuntimeError as exc:
                    print(f"# N = {robots}, run {k + 1}: {exc}", file=sys.stderr)
            if runs and summarise(runs).clearly_fails:
                break  # more runs of a size that clearly fails change nothing
        if not runs:
            print(f"| {robots} | 0 | did not run |")
            break
        figures = summarise(runs)
        results.append(figures)
        records += [asdict(r) for r in runs]
        print(table_row(figures), flush=True)
        if figures.clearly_fails:
            print(
                f"\n# stopped: the median robot of N = {robots} misses more than "
                f"{100 * CLEAR_FAILURE_MISS_SHARE:.0f} % of its deadlines"
            )
            break
    holding = [s.robots for s in results if s.holds]
    largest = max(
        (n for n in holding if all(s.holds for s in results if s.robots <= n)), default=None
    )
    print()
    if largest is None:
        print("largest N that holds: none of the sizes tried")
    else:
        print(f"largest N that holds: {largest}")
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())

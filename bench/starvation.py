"""A real-time swarm on a starved host, with and without the starvation guard (not a test:
prints a table; docs/robustness.md, "CPU starvation", has its figures).

Each run starts a CPU hog of `--hogs` processes (default 4 busy loops on this 2-core machine;
`--hog bursty`: loops that spin 4 ms and sleep 1 ms, which compete for every wake-up;
`--hog swarm`: whole second swarms, as in the run that first showed the problem), then
`swarm up` of the paper scenario (3 robots, real time) for `--duration` simulated seconds, and
reads the run's summary.json: collisions, minimum separations, the real-time factor, control
deadline misses, what the guard did (time held, longest hold, robots passed over), and the
longest time the physics ran past the end of the control period a robot had answered ("max
blind": its body driven by a command that had not seen that time; measured with the guard off
too).  It also follows the ground truth to say who touched what when.  The guard is switched
off for the comparison runs with $SWARM_STARVATION_GUARD=0 (a WorldConfig field,
world/realtime_guard.py); the two settings alternate, so both see the same background load.
The hog is stopped, by PID, when the run ends, whatever happens.

    .venv/bin/python bench/starvation.py [--runs 3] [--hogs 4] [--hog busy|bursty|swarm]
        [--duration 60] [--guard both|on|off] [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from arguments import positive_float, positive_int
from machine import machine_lines
from swarm_up import SwarmUp

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import TruthMessage, parse_message
from robot_firmware.net.session import open_client
from swarm_config.scenario import DEFAULT_SCENARIO_PATH, load_scenario
from world.metrics import obstacle_gaps, robot_gaps

HOG_CODE = {
    "busy": "while True: pass",
    # Busy 4 ms, asleep 1 ms: a hog that also wakes up often competes with the robots for the
    # CPU at every wake-up (the scheduler favours tasks that slept), like a second swarm does.
    "bursty": (
        "import time\n"
        "while True:\n"
        "    t = time.perf_counter()\n"
        "    while time.perf_counter() - t < 0.004:\n"
        "        pass\n"
        "    time.sleep(0.001)\n"
    ),
}
GUARD_ENV = "SWARM_STARVATION_GUARD"


@contextlib.contextmanager
def cpu_hog(processes: int, kind: str) -> Iterator[None]:
    """`processes` hogs for the duration of the block (kind `swarm`: whole second swarms);
    every process they started is killed by PID after."""
    if kind == "swarm":
        with contextlib.ExitStack() as stack:
            for k in range(processes):
                out = Path(stack.enter_context(tempfile.TemporaryDirectory()))
                stack.enter_context(SwarmUp(out, swarm=f"hog{k + 1}")).wait_ticking()
            yield
        return
    hogs = [
        subprocess.Popen([sys.executable, "-c", HOG_CODE[kind]], stdin=subprocess.DEVNULL)
        for _ in range(processes)
    ]
    try:
        yield
    finally:
        for hog in hogs:
            with contextlib.suppress(ProcessLookupError):
                os.kill(hog.pid, signal.SIGKILL)
        for hog in hogs:
            hog.wait(timeout=10)


class TruthWatch:
    """Follows the run's ground truth (`swarm/<swarm>/truth`, 20 Hz) to say who touched what
    when, and when each robot first showed up live.  The callback only keeps the payloads;
    they are read at `close`."""

    def __init__(self, up: SwarmUp) -> None:
        scenario = load_scenario(DEFAULT_SCENARIO_PATH)
        self.names = scenario.robot_names
        self.centres_m, self.radii_m = scenario.obstacle_arrays()
        self.body_radius_m = scenario.robot_body.body_radius_m
        self.contacts: list[str] = []
        self.first_live_s: dict[str, float] = {}
        self._payloads: list[bytes] = []
        self._session = open_client([up.endpoint], credentials=up.operator_credentials())
        self._session.declare_subscriber(
            SwarmKeys(up.swarm).truth,
            lambda sample: self._payloads.append(sample.payload.to_bytes()),
        )

    def close(self) -> None:
        self._session.close()
        touching: set[str] = set()
        onsets: dict[str, list[float]] = {}
        for payload in self._payloads:
            truth = parse_message(TruthMessage, payload)
            if truth is None or any(n not in truth.robots for n in self.names):
                continue
            now = self._touching(truth)
            for pair in now - touching:
                onsets.setdefault(pair, []).append(truth.t_s)
            touching = now
            for name in self.names:
                if truth.robots[name].alive:
                    self.first_live_s.setdefault(name, round(truth.t_s, 2))
        self.contacts = [
            f"{pair} at t = {times[0]:.1f} s"
            + (f" ({len(times)} touches until {times[-1]:.1f} s)" if len(times) > 1 else "")
            for pair, times in sorted(onsets.items())
        ]

    def _touching(self, truth: TruthMessage) -> set[str]:
        xy = np.array([truth.robots[n].pose[:2] for n in self.names], dtype=np.float64)
        to_obstacle = obstacle_gaps(xy, self.centres_m, self.radii_m) - self.body_radius_m
        to_robot = robot_gaps(xy, self.body_radius_m)
        pairs = {f"{self.names[i]} with obstacle {j}" for i, j in np.argwhere(to_obstacle <= 0)}
        pairs |= {
            f"{self.names[i]} with {self.names[j]}" for i, j in np.argwhere(to_robot <= 0) if i < j
        }
        return pairs


@dataclass(frozen=True)
class Run:
    guard: bool
    collisions: int
    min_robot_separation_m: float | None
    min_obstacle_clearance_m: float | None
    real_time_factor: float | None
    deadline_misses: int
    ticks: int
    held_s: float | None
    longest_hold_s: float | None
    lapses: int | None
    max_blind_s: float | None
    """The longest the physics ran past the end of the period a robot had answered."""
    wall_s: float
    contacts: tuple[str, ...] = ()
    first_live_s: tuple[tuple[str, float], ...] = ()


def one_run(guard: bool, hogs: int, kind: str, duration_s: float) -> Run:
    env_before = os.environ.get(GUARD_ENV)
    os.environ[GUARD_ENV] = "1" if guard else "0"
    try:
        with tempfile.TemporaryDirectory() as out, cpu_hog(hogs, kind):
            started_s = time.monotonic()
            with SwarmUp(Path(out), "--duration", str(duration_s)) as up:
                watch = TruthWatch(up)
                try:
                    up.wait(timeout_s=max(600.0, 20 * duration_s))
                finally:
                    watch.close()
                summary = up.summary()
            wall_s = time.monotonic() - started_s
    finally:
        if env_before is None:
            os.environ.pop(GUARD_ENV, None)
        else:
            os.environ[GUARD_ENV] = env_before
    if summary is None:
        raise RuntimeError("the run left no summary.json")
    run = run_from_summary(guard, summary, wall_s)
    return replace(
        run,
        contacts=tuple(watch.contacts),
        first_live_s=tuple(sorted(watch.first_live_s.items())),
    )


def run_from_summary(guard: bool, summary: dict[str, Any], wall_s: float) -> Run:
    timings = [t for t in (summary.get("control_timing") or {}).values() if t]
    held = summary.get("starvation_guard") or {}
    return Run(
        guard=guard,
        collisions=int(summary["collisions"]),
        min_robot_separation_m=summary.get("min_robot_separation_m"),
        min_obstacle_clearance_m=summary.get("min_obstacle_clearance_m"),
        real_time_factor=summary.get("real_time_factor"),
        deadline_misses=sum(int(t["deadline_misses"]) for t in timings),
        ticks=sum(int(t["ticks"]) for t in timings),
        held_s=held.get("held_s") if held.get("enabled") else None,
        longest_hold_s=held.get("longest_hold_s") if held.get("enabled") else None,
        lapses=sum(held.get("lapses", {}).values()) if held.get("enabled") else None,
        max_blind_s=max(held.get("max_blind_s", {}).values(), default=None),
        wall_s=wall_s,
    )


def _cell(value: float | int | None, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def _cm(value_m: float | None) -> str:
    return _cell(None if value_m is None else 100 * value_m, ".1f")


COLUMNS = (
    "guard",
    "collisions",
    "min robot sep. (cm)",
    "min obstacle clear. (cm)",
    "real-time factor",
    "deadline misses",
    "held (s)",
    "longest hold (ms)",
    "passed over",
    "max blind (ms)",
    "wall (s)",
)


def table_row(r: Run) -> list[str]:
    share = 100 * r.deadline_misses / max(r.ticks, 1)
    return [
        "on" if r.guard else "off",
        str(r.collisions),
        _cm(r.min_robot_separation_m),
        _cm(r.min_obstacle_clearance_m),
        _cell(r.real_time_factor, ".2f"),
        f"{r.deadline_misses} of {r.ticks} ({share:.1f} %)",
        _cell(r.held_s, ".1f"),
        _cell(None if r.longest_hold_s is None else 1000 * r.longest_hold_s, ".0f"),
        _cell(r.lapses, "d"),
        _cell(None if r.max_blind_s is None else 1000 * r.max_blind_s, ".0f"),
        f"{r.wall_s:.0f}",
    ]


def print_table(runs: list[Run], hogs: int, kind: str, duration_s: float) -> None:
    print(
        f"\n3-robot real-time swarm (paper scenario, {duration_s:.0f} simulated s) beside "
        f"{hogs} {'second swarm(s)' if kind == 'swarm' else kind + ' processes'}; one line "
        "per run"
    )
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for run in runs:
        print("| " + " | ".join(table_row(run)) + " |")
    for guard in (True, False):
        mine = [r for r in runs if r.guard == guard]
        if not mine:
            continue
        rtf = _median([r.real_time_factor for r in mine])
        print(
            f"guard {'on ' if guard else 'off'}: {len(mine)} runs, collisions "
            f"{sum(r.collisions for r in mine)} in total (in {sum(r.collisions > 0 for r in mine)} "
            f"runs), median real-time factor {_cell(rtf, '.2f')}, deadline misses "
            f"{sum(r.deadline_misses for r in mine)} of {sum(r.ticks for r in mine)}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=positive_int, default=3, help="runs per setting (default 3)")
    parser.add_argument("--hogs", type=positive_int, default=4, help="hog processes (default 4)")
    parser.add_argument(
        "--hog",
        choices=[*sorted(HOG_CODE), "swarm"],
        default="busy",
        help="busy: spin for ever (default); bursty: spin 4 ms, sleep 1 ms; swarm: a whole "
        "second real-time swarm (router, world, 3 robots) per hog",
    )
    parser.add_argument("--duration", type=positive_float, default=60.0, help="simulated s per run")
    parser.add_argument(
        "--guard",
        choices=("both", "on", "off"),
        default="both",
        help="which settings to run (default both, interleaved)",
    )
    parser.add_argument("--json", metavar="FILE", help="also write the runs as JSON")
    args = parser.parse_args()
    settings = {"both": (True, False), "on": (True,), "off": (False,)}[args.guard]
    for line in machine_lines():
        print(line)
    runs = []
    for k in range(args.runs):
        for guard in settings:  # interleaved, so both see the same background load
            run = one_run(guard, args.hogs, args.hog, args.duration)
            print(
                f"run {k + 1} guard {'on' if guard else 'off'}: collisions {run.collisions}, "
                f"real-time factor {_cell(run.real_time_factor, '.2f')}, deadline misses "
                f"{run.deadline_misses} of {run.ticks}; contacts {list(run.contacts)}; robots "
                f"first live at t = {dict(run.first_live_s)} s",
                flush=True,
            )
            runs.append(run)
    print_table(runs, args.hogs, args.hog, args.duration)
    for line in machine_lines():
        print(line.replace("# ", "# at the end: ", 1))
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in runs], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

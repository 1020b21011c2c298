"""The networked swarm's runtime figures (not a test: prints tables).

* lockstep speed-up: simulated seconds per wall second of `swarm up --lockstep`, for the paper
  scenario (3 robots) and a generated 24-robot wedge (`swarm scenario generate --robots 24
  --formation wedge`), with where a tick's wall time goes: the world's phases (tick boundary;
  sense and clock messages encoded and published; waiting for every robot's act and frames;
  gathering them; the physics step; truth and checkpoints) and, per robot, the median time from
  its sense message out to its act message in (two router hops plus the robot's receive, tick
  and act; the raw ping-pong below is what the hops alone cost); and the CPU per tick of the
  router, the world and a robot (every thread, from /proc over the same window), their sum and
  how many of the cores it keeps busy over a tick;
* real time: control-loop deadline misses and period jitter per robot over 32 s runs;
* CPU per process (router, world, each robot) during a real-time run, from /proc;
* radio one-hop overhead with the ideal profile: a frame from `radio/tx/robot1` through the
  world to `radio/rx/robot2`, next to a raw Zenoh ping-pong through the same router (answered
  by a second process, as the world is one) and their ratio (goal: at most 3); and, for
  reference, a ping-pong answered inside the bench's own session, which Zenoh delivers
  without the router (earlier versions of this bench took that one for the raw trip);
* what handing work to another thread costs here: waking a sleeping thread with a
  `threading.Event` and a Zenoh `put` (which wakes Zenoh's transmit thread), each after the
  waker idled 2 ms (as between two ticks) and back to back: the waker's CPU time and the wall
  time, per hand-over.

Every figure is the median of several runs; machine and date are printed.

    .venv/bin/python bench/swarm_runtime.py [--runs 3] [--only lockstep|realtime|hop|wake]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from arguments import positive_int
from machine import machine_lines
from proc_stats import CpuWindow
from swarm_up import SwarmUp, start_router

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import LockstepProfileReport
from robot_firmware.net.session import open_client
from swarm_config.credentials import (
    read_credentials,
)

ROOT = Path(__file__).resolve().parents[1]


WEDGE_ROBOTS = 24


def wedge_scenario(directory: Path, robots: int) -> Path:
    """`swarm scenario generate --robots N --formation wedge` into `directory`."""
    path = directory / f"wedge-{robots}.yaml"
    subprocess.run(
        [sys.executable, "-m", "services.cli.main", "scenario", "generate", "--robots",
         str(robots), "--formation", "wedge", "--out", str(path)],
        cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return path


@dataclass(frozen=True)
class LockstepRun:
    """One lockstep window: simulated seconds per wall second, the world's profile of its
    ticks, and the CPU each process used per tick (ms; robots by name)."""

    speedup: float
    profile: LockstepProfileReport | None
    cpu_ms_per_tick: dict[str, float]


def lockstep_speedup(window_s: float, scenario: Path | None = None) -> LockstepRun:
    """Simulated seconds per wall second over `window_s` of a running lockstep swarm, the
    world's profile of its ticks (since time started) and each process's CPU per tick over the
    same window (/proc: every thread of it, Zenoh's included)."""
    args = ("--lockstep",) if scenario is None else ("--lockstep", "--scenario", str(scenario))
    with tempfile.TemporaryDirectory() as out, SwarmUp(Path(out), *args) as up:
        first = up.wait_ticking(timeout_s=600)
        window = CpuWindow({n: pid for n, pid in up.pids().items() if n != "launcher"})
        t0 = time.monotonic()
        time.sleep(window_s)
        second = up.world_status(timeout_s=10)
        percent = window.percent()
        wall = time.monotonic() - t0
        assert second is not None
        ticks = max(second.tick - first.tick, 1)
        # % of one core over the window -> ms of CPU per tick
        cpu = {name: 10.0 * pct * wall / ticks for name, pct in percent.items() if pct is not None}
        return LockstepRun(
            (second.t_s - first.t_s) / wall,
            window_profile(first.lockstep_profile, second.lockstep_profile),
            cpu,
        )


def window_profile(
    first: LockstepProfileReport | None, second: LockstepProfileReport | None
) -> LockstepProfileReport | None:
    """The ticks between two of the world's profiles (means since time started)."""
    if first is None or second is None or second.ticks <= first.ticks:
        return second
    ticks = second.ticks - first.ticks
    phases = {
        phase: (ms * second.ticks - first.phase_ms_per_tick[phase] * first.ticks) / ticks
        for phase, ms in second.phase_ms_per_tick.items()
    }
    return second.model_copy(update={"ticks": ticks, "phase_ms_per_tick": phases})


def print_lockstep(label: str, runs: list[LockstepRun]) -> None:
    speedups = [run.speedup for run in runs]
    print(
        f"lockstep speed-up over real time, {label}: {statistics.median(speedups):.2f}x "
        f"(runs: {', '.join(f'{s:.2f}' for s in speedups)})"
    )
    profiles = [run.profile for run in runs if run.profile is not None]
    if not profiles:
        return
    phases = list(profiles[0].phase_ms_per_tick)
    total = statistics.median(sum(p.phase_ms_per_tick.values()) for p in profiles)
    print(f"  {'phase of a tick (wall ms, mean)':<34} {'ms':>7} {'share':>6}")
    for phase in phases:
        ms = statistics.median(p.phase_ms_per_tick[phase] for p in profiles)
        print(f"  {phase:<34} {ms:>7.3f} {100 * ms / total:>5.0f}%")
    print(f"  {'tick':<34} {total:>7.3f}")
    answers = [ms for p in profiles for ms in p.answer_p50_ms.values()]
    if answers:
        print(
            f"  robot answer (sense out -> act in), median over robots of p50: "
            f"{statistics.median(answers):.3f} ms (min {min(answers):.3f}, max {max(answers):.3f})"
        )
    print_cpu_per_tick(runs, total)


def print_cpu_per_tick(runs: list[LockstepRun], tick_ms: float) -> None:
    """CPU per tick by process (ms, median of the runs; a robot: the median robot), their sum,
    and how many of the cores that sum keeps busy for a tick's wall time."""
    per_run: list[dict[str, float]] = []
    for run in runs:
        robots = [ms for name, ms in run.cpu_ms_per_tick.items() if name.startswith("robot")]
        if not robots:
            continue
        per_run.append(
            {
                "router": run.cpu_ms_per_tick.get("router", float("nan")),
                "world": run.cpu_ms_per_tick.get("world", float("nan")),
                "robot (median)": statistics.median(robots),
                "all processes": sum(run.cpu_ms_per_tick.values()),
            }
        )
    if not per_run:
        return
    print(f"  {'CPU per tick (ms, all threads)':<34} {'ms':>7}")
    for name in per_run[0]:
        print(f"  {name:<34} {statistics.median(r[name] for r in per_run):>7.3f}")
    busy = statistics.median(r["all processes"] for r in per_run) / tick_ms
    print(f"  {'cores busy over a tick':<34} {busy:>7.2f}")


def realtime_run() -> tuple[dict, dict[str, float | None]]:
    with tempfile.TemporaryDirectory() as out:
        with SwarmUp(Path(out), "--duration", "32") as up:
            up.wait_ticking()
            cpu = CpuWindow(up.pids())
            time.sleep(10.0)
            percent = cpu.percent()
            up.wait(timeout_s=120)
        summary = up.summary()
        assert summary is not None
    return summary["control_timing"], percent


ECHO_PROCESS = """
import sys, time
from pathlib import Path
from robot_firmware.net.session import open_client
from swarm_config.credentials import read_credentials
with open_client([sys.argv[1]], credentials=read_credentials(Path(sys.argv[2]))) as session:
    pong = session.declare_publisher("bench/pong")
    session.declare_subscriber("bench/ping", lambda sample: pong.put(sample.payload.to_bytes()))
    session.declare_subscriber("bench/sink", lambda sample: None)
    print("echo up", flush=True)
    sys.stdin.read()
"""
"""A second process that answers `bench/ping` on `bench/pong` from its subscriber's callback:
the raw round trip through the router that the radio hop is compared with; it also takes
`bench/sink` and does nothing with it."""


CLI = [sys.executable, "-m", "services.cli.main"]


def quiet(args: list[str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@contextlib.contextmanager
def router_and_echo() -> Iterator[tuple[str, dict[str, Path]]]:
    """A router with the run's logins but no access control (the bench plays robots and uses
    keys of its own), and `ECHO_PROCESS` logged in as robot3: the endpoint and the
    credential files."""
    credentials_dir = Path(tempfile.mkdtemp()) / "credentials"
    endpoint, files, router = start_router(
        credentials_dir, "lab", ["robot1", "robot2", "robot3"], access_control=False
    )
    echo = subprocess.Popen(
        [sys.executable, "-c", ECHO_PROCESS, endpoint, str(files["robot3"])],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert echo.stdout is not None and echo.stdout.readline().strip() == "echo up"
        yield endpoint, files
    finally:
        echo.communicate(timeout=30)
        router.terminate()
        router.wait(timeout=30)


def one_hop_latency_ms(samples: int) -> dict[str, list[float]]:
    """Radio hop through the world (ideal profile); a raw ping-pong through the router to a
    second process (`ECHO_PROCESS`); and a ping-pong answered inside the bench's own session,
    which Zenoh delivers without the router."""
    keys = SwarmKeys("lab")
    with router_and_echo() as (endpoint, files):
        scenario = ["--scenario", "configs/scenarios/paper.yaml", "--radio", "ideal"]
        login = ["--connect", endpoint, "--credentials", str(files["world"])]
        world = quiet([*CLI, "world", *scenario, *login])
        try:
            return _hop_figures(endpoint, files, keys, samples)
        finally:
            world.terminate()
            world.wait(timeout=30)


def _hop_figures(
    endpoint: str, files: dict[str, Path], keys: SwarmKeys, samples: int
) -> dict[str, list[float]]:
    """The three paths timed in interleaved rounds, `samples` each."""
    with open_client([endpoint], credentials=read_credentials(files["operator"])) as session:
        got = threading.Event()
        arrived: list[int] = []

        def on_rx(sample) -> None:  # type: ignore[no-untyped-def]
            arrived.append(time.perf_counter_ns())
            got.set()

        session.declare_subscriber(keys.radio_rx("robot2"), on_rx)
        session.declare_subscriber("bench/pong", on_rx)
        local = session.declare_subscriber(
            "bench/local-ping", lambda s: session.put("bench/pong", s.payload.to_bytes())
        )
        time.sleep(2.0)

        def measure(key: str, count: int) -> list[float]:
            out = []
            for k in range(count):
                got.clear()
                start = time.perf_counter_ns()
                session.put(key, k.to_bytes(8, "little") * 11)
                if got.wait(1.0):
                    out.append((arrived[-1] - start) / 1e6)
                time.sleep(0.005)
            return out

        paths = {
            "radio": keys.radio_tx("robot1"),
            "router": "bench/ping",
            "session": "bench/local-ping",
        }
        for key in paths.values():
            measure(key, 50)  # warm up
        # Interleaved in rounds, so that the machine's load weighs on every path alike.
        figures: dict[str, list[float]] = {name: [] for name in paths}
        rounds = 10
        for _ in range(rounds):
            for name, key in paths.items():
                figures[name] += measure(key, max(samples // rounds, 1))
        local.undeclare()
        return figures


IDLE_BEFORE_S = 0.002
"""How long the waker sleeps before each timed wake-up: as a robot between two ticks."""


def wake_costs_us(samples: int) -> dict[str, tuple[float, float]]:
    """What handing work to another thread costs on this machine, per path: (p50 of the
    waker's own CPU time, p50 of the wall time) in µs.  A robot does this a few times per
    tick (Zenoh's callback thread waking the control loop, each first `put` of a tick waking
    Zenoh's transmit thread), the world per tick and per frame."""
    figures: dict[str, tuple[float, float]] = {}
    wake, woken = threading.Event(), threading.Event()

    def waiter() -> None:
        while True:
            wake.wait()
            wake.clear()
            woken.set()

    threading.Thread(target=waiter, daemon=True).start()

    def timed(action: Callable[[], None], idle_s: float) -> tuple[float, float]:
        cpu, wall = [], []
        for _ in range(samples):
            if idle_s:
                time.sleep(idle_s)
            t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            action()
            cpu.append(time.thread_time_ns() - c0)
            wall.append(time.perf_counter_ns() - t0)
        return statistics.median(cpu) / 1e3, statistics.median(wall) / 1e3

    def event_round_trip() -> None:
        wake.set()
        woken.wait()
        woken.clear()

    figures["event_idle"] = timed(event_round_trip, IDLE_BEFORE_S)
    figures["event_busy"] = timed(event_round_trip, 0.0)
    with contextlib.ExitStack() as stack:
        endpoint, files = stack.enter_context(router_and_echo())
        operator = read_credentials(files["operator"])
        session = stack.enter_context(open_client([endpoint], credentials=operator))
        sink = session.declare_publisher("bench/sink")
        payload = bytes(96)
        time.sleep(1.0)
        figures["put_idle"] = timed(lambda: sink.put(payload), IDLE_BEFORE_S)
        figures["put_busy"] = timed(lambda: sink.put(payload), 0.0)
    return figures


def wake_table(samples: int, runs: int) -> None:
    results = [wake_costs_us(samples) for _ in range(runs)]
    labels = {
        "event_idle": "threading.Event wake-up and answer, after 2 ms idle",
        "event_busy": "threading.Event wake-up and answer, back to back",
        "put_idle": "Zenoh put through the router, after 2 ms idle",
        "put_busy": "Zenoh put through the router, back to back",
    }
    print(f"{'hand-over to another thread':<54} {'CPU µs':>7} {'wall µs':>8}")
    for name, label in labels.items():
        cpu = statistics.median(r[name][0] for r in results)
        wall = statistics.median(r[name][1] for r in results)
        print(f"{label:<54} {cpu:>7.1f} {wall:>8.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=positive_int, default=3)
    parser.add_argument("--samples", type=positive_int, default=500)
    parser.add_argument("--only", choices=("lockstep", "realtime", "hop", "wake"), default=None)
    args = parser.parse_args()
    print("# networked swarm runtime")
    for line in machine_lines():
        print(line)
    print(f"# paper scenario, 3 robots, unless said; median of {args.runs} runs")
    print()
    if args.only in (None, "lockstep"):
        print_lockstep("3 robots (goal 10x)", [lockstep_speedup(10.0) for _ in range(args.runs)])
        with tempfile.TemporaryDirectory() as scenarios:
            wedge = wedge_scenario(Path(scenarios), WEDGE_ROBOTS)
            print_lockstep(
                f"{WEDGE_ROBOTS}-robot wedge (goal 3x)",
                [lockstep_speedup(20.0, wedge) for _ in range(args.runs)],
            )
        print()
    if args.only in (None, "realtime"):
        realtime_tables(args.runs)
        print()
    if args.only in (None, "hop"):
        hop_table(args.samples, args.runs)
        print()
    if args.only in (None, "wake"):
        wake_table(args.samples, args.runs)


def realtime_tables(runs: int) -> None:
    timings, cpus = zip(*(realtime_run() for _ in range(runs)), strict=True)
    print(f"{'robot':<8} {'ticks':>6} {'misses':>7} {'miss %':>7} {'jitter p99 ms':>14}")
    for name in sorted(timings[0]):
        rows = [t[name] for t in timings]
        ticks = statistics.median(r["ticks"] for r in rows)
        misses = statistics.median(r["deadline_misses"] for r in rows)
        jitter = statistics.median(r["period_jitter_p99_ms"] for r in rows)
        print(
            f"{name:<8} {ticks:>6.0f} {misses:>7.0f} {100 * misses / ticks:>6.2f}% {jitter:>14.2f}"
        )
    print()
    print(f"{'process':<8} {'CPU % of one core':>18}")
    for name in cpus[0]:
        values = [c[name] for c in cpus if c.get(name) is not None]
        print(f"{name:<8} {statistics.median(values) if values else float('nan'):>18.1f}")


def hop_table(samples: int, runs: int) -> None:
    """Per path, p50 and p99 of each run; the median over the runs, and the ratio per run."""
    results = [one_hop_latency_ms(samples) for _ in range(runs)]
    labels = {
        "radio": "robot1 -> world -> robot2 (radio hop)",
        "router": "raw ping-pong via the router",
        "session": "ping-pong inside one session (no router)",
    }
    print(f"{'path (ideal profile)':<42} {'p50 ms':>7} {'p99 ms':>7} {'n':>5}")
    for name, label in labels.items():
        p50 = statistics.median(np.percentile(r[name], 50) for r in results)
        p99 = statistics.median(np.percentile(r[name], 99) for r in results)
        count = sum(len(r[name]) for r in results)
        print(f"{label:<42} {p50:>7.3f} {p99:>7.3f} {count:>5}")
    ratios = [np.percentile(r["radio"], 50) / np.percentile(r["router"], 50) for r in results]
    within = [np.percentile(r["radio"], 50) / np.percentile(r["session"], 50) for r in results]
    print(
        f"radio hop / raw ping-pong via the router, p50: {statistics.median(ratios):.2f}x "
        f"(runs {', '.join(f'{x:.2f}' for x in ratios)}; goal at most 3x)"
    )
    print(
        f"radio hop / ping-pong inside one session, p50: {statistics.median(within):.2f}x "
        f"(runs {', '.join(f'{x:.2f}' for x in within)})"
    )


if __name__ == "__main__":
    main()

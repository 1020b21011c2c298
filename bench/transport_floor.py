"""What the transport alone costs a real-time swarm of N robots (prints a table).

A robot process is its firmware plus its part of the swarm's messaging: 100 sense messages a
second in, an act out for each, a radio frame and a telemetry message out 20 times a second,
and 20 (N - 1) peers' frames in, all through the router.  This bench runs that messaging with
no firmware at all, to find the floor under any robot process of this design:

* a router started as `swarm up` starts it (`swarm router`, the run's logins and access
  control for N robots);
* N stand-in robots, each its own process logged in with its robot's credentials, declaring
  what a robot declares (sense and radio subscribers, act, radio and telemetry publishers,
  admin queryable, liveliness token and subscriber) and doing what its main loop does with
  the network: the sense callback queues and wakes the loop, frames wait in a Zenoh ring
  channel until the loop takes them, and for every sense message the loop puts a frame (every
  fifth), the act, and telemetry (every fifth);
* a stand-in world, its own process: every 10 ms it puts N sense messages and the clock, the
  truth every fifth tick, relays every frame to the N - 1 other robots on a thread of its own
  (as world/runtime.py `_relay_frames` does, without drawing links: the frames one relay pass
  has for a receiver in one bundle, robot_firmware/net/radio_bundle.py), and takes every act
  and telemetry message.

Every payload is a real one, of the robots' and world's own encoders, taken from a generated
wedge of N robots run for a few periods in this process (bench/robot_period.py
`closed_loop_period`).  CPU per process (% of one core, /proc) is measured over `--duration`
seconds after the stand-ins are up; the stand-in world reports how late its ticks left (p99)
and the stand-in robots what share of the sense messages they answered.  Unless `--no-swarm`,
the same N then runs as a real `swarm up` (bench/scale.py `run_once`) and its robots', world's
and router's CPU stand beside the floor's, so the share of a robot process that is transport
is a ratio of one run.  Each row is the median of `--repeats` runs.

With `--per-frame-rx` every floor run is followed by a second one in which the stand-in world
puts every frame on its own for each receiver (a bundle of one), as the world did before it
bundled: what the bundles save of the radio's N (N - 1) fan-out.  Its rows say `frame` in the
relay column (the world's own way says `pass`), and "frames/put" is how many frames a
`radio/rx` message carried on average, as measured.

    .venv/bin/python bench/transport_floor.py [--sizes 3,12,24,30] [--duration 20]
                                              [--repeats 3] [--no-swarm] [--per-frame-rx]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from arguments import positive_float, positive_int

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SWARM = "lab"
PERIOD_NS = 10_000_000
FIFTH = 5
"""Frames, telemetry and truth go out every fifth control period (20 Hz)."""
CAPTURE_PERIODS = 60
UP_TIMEOUT_S = 120.0
DEFAULT_SIZES = (3, 12, 24, 30)


def _stop_at_eof(stop: threading.Event, wake: threading.Event) -> None:
    """A stand-in ends when its parent closes its standard input (or dies)."""
    sys.stdin.read()
    stop.set()
    wake.set()


def drain(queue: deque[Any]) -> int:
    """Take everything queued (as a main loop takes its callbacks' queue); how many."""
    taken = 0
    while queue:
        queue.popleft()
        taken += 1
    return taken


def stand_in_robot(endpoint: str, credentials: Path, payloads: dict[str, Any], name: str) -> None:
    """A robot process's messaging without its firmware (module docstring)."""
    import zenoh

    from robot_firmware.net.keys import SwarmKeys
    from robot_firmware.net.radio_bundle import FRAME_RING, split_bundle
    from robot_firmware.net.session import open_client
    from swarm_config.credentials import read_credentials

    keys = SwarmKeys(SWARM)
    act = bytes.fromhex(payloads["act"][name])
    frame = bytes.fromhex(payloads["frame"][name])
    telemetry = bytes.fromhex(payloads["telemetry"][name])
    sense: deque[tuple[bytes, int]] = deque(maxlen=64)
    frames: deque[bytes] = deque(maxlen=1024)
    tokens: deque[str] = deque(maxlen=1024)
    wake, stop = threading.Event(), threading.Event()
    threading.Thread(target=_stop_at_eof, args=(stop, wake), daemon=True).start()

    def on_sense(sample: Any) -> None:
        sense.append((sample.payload.to_bytes(), time.monotonic_ns()))
        wake.set()

    def on_token(sample: Any) -> None:
        tokens.append(str(sample.key_expr))

    answered = frames_taken = 0
    with open_client([endpoint], None, read_credentials(credentials)) as session:
        session.declare_subscriber(keys.sense(name), on_sense)
        ring = session.declare_subscriber(
            keys.radio_rx(name), zenoh.handlers.RingChannel(FRAME_RING)
        )
        session.declare_queryable(keys.admin(name, "*"), lambda query: None)
        act_pub = session.declare_publisher(keys.act(name))
        tx_pub = session.declare_publisher(keys.radio_tx(name))
        telemetry_pub = session.declare_publisher(keys.telemetry(name))
        token = session.liveliness().declare_token(keys.alive("robot", name))
        session.liveliness().declare_subscriber(keys.alive_all("robot"), on_token, history=True)
        print("up", flush=True)
        while not stop.is_set():
            wake.wait(0.05)
            wake.clear()
            while sense:
                sense.popleft()
                answered += 1
                # As a real period: the frames taken, then frame, act and telemetry put.
                while (bundle := ring.try_recv()) is not None:
                    frames.extend(split_bundle(bundle.payload.to_bytes()))
                frames_taken += drain(frames)
                if answered % FIFTH == 0:
                    tx_pub.put(frame)
                act_pub.put(act)
                if answered % FIFTH == 0:
                    telemetry_pub.put(telemetry)
        token.undeclare()
    print(json.dumps({"answered": answered, "frames": frames_taken}))


def stand_in_world(
    endpoint: str, credentials: Path, payloads: dict[str, Any], per_frame_rx: bool
) -> None:
    """The world's messaging without its engine (module docstring)."""
    from robot_firmware.net.keys import SwarmKeys
    from robot_firmware.net.radio_bundle import bundle_frames
    from robot_firmware.net.session import open_client
    from swarm_config.credentials import read_credentials

    keys = SwarmKeys(SWARM)
    names = list(payloads["sense"])
    sense = [bytes.fromhex(payloads["sense"][name]) for name in names]
    clock = bytes.fromhex(payloads["clock"])
    truth = bytes.fromhex(payloads["truth"])
    wake, stop = threading.Event(), threading.Event()
    threading.Thread(target=_stop_at_eof, args=(stop, wake), daemon=True).start()
    acts: deque[tuple[str, bytes]] = deque()
    telemetry: deque[bytes] = deque()
    queued_frames: deque[tuple[str, bytes]] = deque()
    frame_queued = threading.Event()
    alive: set[str] = set()

    def on_act(sample: Any) -> None:
        acts.append((str(sample.key_expr), sample.payload.to_bytes()))

    def on_telemetry(sample: Any) -> None:
        telemetry.append(sample.payload.to_bytes())

    def on_frame(sample: Any) -> None:
        queued_frames.append((str(sample.key_expr), sample.payload.to_bytes()))
        frame_queued.set()

    def on_alive(sample: Any) -> None:
        alive.add(SwarmKeys.last_chunk(str(sample.key_expr)))

    relayed = rx_puts = 0

    def relay(rx_pubs: dict[str, Any]) -> None:
        nonlocal relayed, rx_puts
        while not stop.is_set():
            frame_queued.wait(0.05)
            frame_queued.clear()
            taken: list[tuple[str, bytes]] = []
            while queued_frames:
                key, payload = queued_frames.popleft()
                taken.append((SwarmKeys.last_chunk(key), payload))
            if per_frame_rx:  # frame by frame, in arrival order, each alone
                for sender, payload in taken:
                    (alone,) = bundle_frames([payload])
                    for receiver, publisher in rx_pubs.items():
                        if receiver != sender:
                            publisher.put(alone)
                            relayed += 1
                            rx_puts += 1
                continue
            for receiver, publisher in rx_pubs.items():  # as the world does
                theirs = [payload for sender, payload in taken if sender != receiver]
                for bundle in bundle_frames(theirs):
                    publisher.put(bundle)
                    rx_puts += 1
                relayed += len(theirs)

    late_ns: list[int] = []
    acts_taken = telemetry_taken = ticks = 0
    with open_client([endpoint], None, read_credentials(credentials)) as session:
        session.declare_subscriber(keys.act_all, on_act)
        session.declare_subscriber(keys.radio_tx_all, on_frame)
        session.declare_subscriber(keys.telemetry_all, on_telemetry)
        session.liveliness().declare_subscriber(keys.alive_all("robot"), on_alive, history=True)
        session.declare_queryable(keys.admin("world", "*"), lambda query: None)
        sense_pubs = [session.declare_publisher(keys.sense(name)) for name in names]
        rx_pubs = {name: session.declare_publisher(keys.radio_rx(name)) for name in names}
        clock_pub = session.declare_publisher(keys.clock)
        truth_pub = session.declare_publisher(keys.truth)
        token = session.liveliness().declare_token(keys.alive("world", "world"))
        relay_thread = threading.Thread(target=relay, args=(rx_pubs,), daemon=True)
        relay_thread.start()
        deadline = time.monotonic() + UP_TIMEOUT_S
        while len(alive) < len(names) and not stop.is_set() and time.monotonic() < deadline:
            time.sleep(0.05)
        print("up", flush=True)
        next_ns = time.monotonic_ns()
        while not stop.is_set():
            now_ns = time.monotonic_ns()
            if now_ns < next_ns:
                stop.wait((next_ns - now_ns) / 1e9)
                continue
            late_ns.append(now_ns - next_ns)
            for publisher, payload in zip(sense_pubs, sense, strict=True):
                publisher.put(payload)
            clock_pub.put(clock)
            if ticks % FIFTH == 0:
                truth_pub.put(truth)
            ticks += 1
            next_ns += PERIOD_NS
            acts_taken += drain(acts)
            telemetry_taken += drain(telemetry)
        relay_thread.join(timeout=5)
        token.undeclare()
    late_ns.sort()
    p99 = late_ns[int(0.99 * (len(late_ns) - 1))] / 1e6 if late_ns else None
    print(
        json.dumps(
            {
                "ticks": ticks,
                "acts": acts_taken,
                "telemetry": telemetry_taken,
                "relayed": relayed,
                "rx_puts": rx_puts,
                "late_p99_ms": p99,
            }
        )
    )


def real_payloads(robots: int, work: Path) -> dict[str, Any]:
    """Each robot's sense, act, frame and telemetry payload and the world's clock and truth
    messages, from a wedge of `robots` run closed-loop for `CAPTURE_PERIODS` periods."""
    from robot_period import build, closed_loop_period

    from robot_firmware.net.messages import RobotTruth, TruthMessage
    from robot_firmware.net.wire import ClockMessage, encode_clock

    world, processes = build(robots, work)
    names = [process.config.name for process in processes]
    kept: dict[str, dict[str, str]] = {kind: {} for kind in ("sense", "act", "frame", "telemetry")}
    for period in range(CAPTURE_PERIODS):
        out = closed_loop_period(world, processes, period)
        for index, name in enumerate(names):
            kept["sense"][name] = out.sense[index].hex()
            kept["act"][name] = out.act[index].hex()
            if out.frames[index]:
                kept["frame"][name] = out.frames[index][-1].hex()
            if out.telemetry[index]:
                kept["telemetry"][name] = out.telemetry[index][-1].hex()
    missing = [(kind, n) for kind, got in kept.items() for n in names if n not in got]
    if missing:
        raise SystemExit(f"no payload in {CAPTURE_PERIODS} periods for {missing[:4]}")
    reference, _ = world.trajectory.evaluate(world.t_s)
    truth = TruthMessage(
        t_s=world.t_s,
        tick=CAPTURE_PERIODS,
        robots={
            name: RobotTruth(pose=tuple(float(v) for v in world.bodies.pose[i]), alive=True)
            for i, name in enumerate(names)
        },
        reference=tuple(float(v) for v in reference),
    )
    clock = encode_clock(ClockMessage(CAPTURE_PERIODS, world.t_ns, PERIOD_NS, False, 0))
    return {**kept, "clock": clock.hex(), "truth": truth.to_json_bytes().hex()}


@dataclass
class FloorRun:
    robots: int
    cpu_percent: dict[str, float | None]
    late_p99_ms: float | None
    answered_share: float
    """Least share, over the stand-in robots, of the world's ticks each answered."""
    frames_per_rx_put: float | None
    """Frames a `radio/rx` message carried on average (1 with `--per-frame-rx`)."""
    payload_bytes: dict[str, float]
    rss_mib: dict[str, float | None]


def run_floor(robots: int, duration_s: float, work: Path, per_frame_rx: bool = False) -> FloorRun:
    from proc_stats import CpuWindow, memory_mib
    from swarm_up import start_router

    payloads = real_payloads(robots, work)
    payload_file = work / "payloads.json"
    payload_file.write_text(json.dumps(payloads), encoding="utf-8")
    names = list(payloads["sense"])
    endpoint, files, router = start_router(
        work / "credentials", SWARM, names, log=(work / "router.log").open("wb")
    )
    this = str(Path(__file__).resolve())
    common = ["--endpoint", endpoint, "--payloads", str(payload_file)]
    if per_frame_rx:
        common.append("--per-frame-rx")
    children: dict[str, subprocess.Popen[Any]] = {"router": router}

    def spawn(name: str, args: list[str]) -> subprocess.Popen[str]:
        child = subprocess.Popen(
            args,
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=(work / f"{name}.log").open("w"),
            text=True,
        )
        children[name] = child
        return child

    try:
        for name in names:
            spawn(
                name,
                [
                    sys.executable,
                    this,
                    "--stand-in",
                    "robot",
                    "--name",
                    name,
                    "--credentials",
                    str(files[name]),
                    *common,
                ],
            )
        for name in names:
            _expect_line(children[name], "up", name)
        world = spawn(
            "world",
            [
                sys.executable,
                this,
                "--stand-in",
                "world",
                "--credentials",
                str(files["world"]),
                *common,
            ],
        )
        _expect_line(world, "up", "world")
        time.sleep(3.0)  # the first ticks and the router's routes settle
        pids = {name: child.pid for name, child in children.items()}
        window = CpuWindow(pids)
        time.sleep(duration_s)
        cpu = window.percent()
        memory = memory_mib(pids)
        reports = {}
        # The world first: every sense message it sent is then in, or on its way to, a robot.
        for name in ("world", *names):
            out, _ = children[name].communicate(timeout=60)
            reports[name] = json.loads(out.strip().splitlines()[-1])
    finally:
        for child in children.values():
            if child.poll() is None:
                child.kill()
                child.wait(timeout=30)
    ticks = reports["world"]["ticks"]
    answered = min(reports[name]["answered"] for name in names) / ticks if ticks else 0.0
    sizes = {
        kind: statistics.mean(len(bytes.fromhex(v)) for v in payloads[kind].values())
        for kind in ("sense", "act", "frame", "telemetry")
    }
    sizes["truth"] = len(bytes.fromhex(payloads["truth"]))
    rx_puts = reports["world"]["rx_puts"]
    return FloorRun(
        robots=robots,
        cpu_percent=cpu,
        late_p99_ms=reports["world"]["late_p99_ms"],
        answered_share=answered,
        frames_per_rx_put=reports["world"]["relayed"] / rx_puts if rx_puts else None,
        payload_bytes=sizes,
        rss_mib={name: rss for name, (rss, _) in memory.items()},
    )


def _expect_line(child: subprocess.Popen[str], line: str, name: str) -> None:
    assert child.stdout is not None
    got = child.stdout.readline().strip()
    if got != line:
        raise RuntimeError(f"stand-in {name} said {got!r} instead of {line!r}; see its log")


def messages_per_second(robots: int, frames_per_rx_put: float | None = None) -> int:
    """Messages the router forwards a second: sense, act, clock; at 20 Hz each robot's frame,
    its N - 1 deliveries (in `radio/rx` messages of `frames_per_rx_put` frames) and its
    telemetry; the truth."""
    per_tick = robots * 2 + 1
    deliveries = (robots - 1) / (frames_per_rx_put or 1.0)
    per_fifth = robots * (1 + deliveries + 1) + 1
    return round(per_tick * 100 + per_fifth * 20)


def total_cores(cpu: dict[str, float | None]) -> float:
    return sum(v for v in cpu.values() if v is not None) / 100.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--sizes",
        default=",".join(map(str, DEFAULT_SIZES)),
        help="robot counts, comma-separated (default 3,12,24,30)",
    )
    parser.add_argument(
        "--duration", type=positive_float, default=20.0, help="measured seconds (20)"
    )
    parser.add_argument("--repeats", type=positive_int, default=3, help="runs per size, median (3)")
    parser.add_argument(
        "--no-swarm",
        dest="swarm",
        action="store_false",
        help="skip the real `swarm up` run beside each floor run",
    )
    parser.add_argument(
        "--per-frame-rx",
        action="store_true",
        help="after each floor run, run it again with every frame put on its own for each "
        "receiver, not one bundle per receiver and relay pass (rows marked 'frame')",
    )
    parser.add_argument("--stand-in", choices=("robot", "world"), help=argparse.SUPPRESS)
    parser.add_argument("--name", help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", help=argparse.SUPPRESS)
    parser.add_argument("--credentials", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--payloads", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.stand_in is not None:
        payloads = json.loads(args.payloads.read_text(encoding="utf-8"))
        if args.stand_in == "robot":
            stand_in_robot(args.endpoint, args.credentials, payloads, args.name)
        else:
            stand_in_world(args.endpoint, args.credentials, payloads, args.per_frame_rx)
        return 0
    try:
        sizes = [int(part) for part in args.sizes.split(",") if part.strip()]
    except ValueError:
        parser.error(f"--sizes: comma-separated whole numbers, not {args.sizes!r}")
    if not sizes or min(sizes) < 2:
        parser.error("--sizes: at least one size, each of 2 robots or more")

    from machine import machine_lines
    from scale import run_once

    print("# the transport alone: N stand-in robots and a stand-in world through the router")
    for line in machine_lines():
        print(line)
    print(
        f"# {args.duration:.0f} s windows, median of {args.repeats} runs (answered: the least); "
        "CPU in % of one core (/proc); "
        "'swarm' is a real `swarm up` of the same N right after"
    )
    print()
    header = (
        f"{'N':>3} {'relay':>5} {'frames/put':>10} {'msgs/s':>7} | "
        f"{'floor robot':>11} {'world':>6} {'router':>6} "
        f"{'cores':>6} {'late p99':>8} {'answered':>8} | {'swarm robot':>11} {'world':>6} "
        f"{'router':>6} {'cores':>6} | {'floor/swarm robot':>17}"
    )
    print(header)
    print("-" * len(header), flush=True)
    floors = []
    with tempfile.TemporaryDirectory(prefix="transport-floor-") as tmp:
        for robots in sizes:
            runs, per_frame_runs = [], []
            for repeat in range(args.repeats):
                work = Path(tmp) / f"floor-{robots}-{repeat}"
                work.mkdir()
                floor = run_floor(robots, args.duration, work)
                floors.append(floor)
                if args.per_frame_rx:
                    per_frame_work = Path(tmp) / f"per-frame-{robots}-{repeat}"
                    per_frame_work.mkdir()
                    per_frame = run_floor(robots, args.duration, per_frame_work, per_frame_rx=True)
                    per_frame_runs.append(run_figures(per_frame, None))
                swarm = None
                if args.swarm:
                    swarm_work = Path(tmp) / f"swarm-{robots}-{repeat}"
                    swarm_work.mkdir()
                    try:
                        swarm = run_once(robots, args.duration, 1, swarm_work).cpu_percent
                    except RuntimeError as exc:
                        print(f"# swarm of {robots}, run {repeat + 1}: {exc}", flush=True)
                runs.append(run_figures(floor, swarm))
            print(table_row(robots, "pass", runs), flush=True)
            if per_frame_runs:
                print(table_row(robots, "frame", per_frame_runs), flush=True)
    robot_rss = [
        v for floor in floors for n, v in floor.rss_mib.items() if n.startswith("robot") and v
    ]
    if robot_rss:
        print(f"# stand-in robot RSS: median {statistics.median(robot_rss):.0f} MiB")
    sizes_line = ", ".join(f"{kind} {size:.0f}" for kind, size in floors[-1].payload_bytes.items())
    print(f"# payload bytes: {sizes_line} (N = {floors[-1].robots})")
    return 0


def run_figures(floor: FloorRun, swarm: dict[str, float | None] | None) -> dict[str, float | None]:
    """One run's row: the floor's and the real swarm's CPU, and the robot's ratio of the two."""
    from scale import _median, _robots_of

    floor_robot = statistics.median(_robots_of(floor.cpu_percent))
    swarm_robot = _median(_robots_of(swarm)) if swarm else None
    return {
        "floor_robot": floor_robot,
        "floor_world": floor.cpu_percent.get("world"),
        "floor_router": floor.cpu_percent.get("router"),
        "floor_cores": total_cores(floor.cpu_percent),
        "late_p99_ms": floor.late_p99_ms,
        "answered_pct": 100 * floor.answered_share,
        "frames_per_rx_put": floor.frames_per_rx_put,
        "swarm_robot": swarm_robot,
        "swarm_world": swarm.get("world") if swarm else None,
        "swarm_router": swarm.get("router") if swarm else None,
        "swarm_cores": total_cores(swarm) if swarm else None,
        "ratio": floor_robot / swarm_robot if swarm_robot else None,
    }


def table_row(robots: int, relay: str, runs: list[dict[str, float | None]]) -> str:
    """The median over the runs of every figure (the answered share: the least)."""
    from scale import _cell, _median

    def median(key: str) -> float | None:
        return _median([run[key] for run in runs])

    answered = min((run["answered_pct"] or 0.0) for run in runs)
    return (
        f"{robots:>3} {relay:>5} {_cell(median('frames_per_rx_put'), '.2f'):>10} "
        f"{messages_per_second(robots, median('frames_per_rx_put')):>7} | "
        f"{_cell(median('floor_robot'), '.1f'):>11} {_cell(median('floor_world'), '.1f'):>6} "
        f"{_cell(median('floor_router'), '.1f'):>6} {_cell(median('floor_cores'), '.2f'):>6} "
        f"{_cell(median('late_p99_ms'), '.2f'):>8} {answered:>7.1f}% | "
        f"{_cell(median('swarm_robot'), '.1f'):>11} {_cell(median('swarm_world'), '.1f'):>6} "
        f"{_cell(median('swarm_router'), '.1f'):>6} {_cell(median('swarm_cores'), '.2f'):>6} | "
        f"{_cell(median('ratio'), '.2f'):>17}"
    )


if __name__ == "__main__":
    sys.exit(main())

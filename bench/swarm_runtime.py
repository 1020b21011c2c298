"""The networked swarm's runtime figures (not a test: prints tables).

* lockstep speed-up: simulated seconds per wall second of `swarm up --lockstep`, 3 robots;
* real time: control-loop deadline misses and period jitter per robot over 32 s runs;
* CPU per process (router, world, each robot) during a real-time run, from /proc;
* radio one-hop overhead with the ideal profile: a frame from `radio/tx/robot1` through the
  world to `radio/rx/robot2`, next to a raw Zenoh ping-pong through the same router.

Every figure is the median of several runs; machine and date are printed.

    .venv/bin/python bench/swarm_runtime.py [--runs 3]
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
from pathlib import Path

import numpy as np
from machine import machine_lines
from proc_stats import CpuWindow
from swarm_up import SwarmUp, free_port

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from services.router.access import router_config_document
from swarm_config.credentials import (
    generate_credential_set,
    read_credentials,
    write_credential_set,
    write_private_file,
)

ROOT = Path(__file__).resolve().parents[1]


def lockstep_speedup(window_s: float) -> float:
    with tempfile.TemporaryDirectory() as out, SwarmUp(Path(out), "--lockstep") as up:
        first = up.wait_ticking()
        t0 = time.monotonic()
        time.sleep(window_s)
        second = up.world_status()
        wall = time.monotonic() - t0
        assert second is not None
        return (second.t_s - first.t_s) / wall


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


def one_hop_latency_ms(samples: int) -> tuple[list[float], list[float]]:
    """Radio hop through the world (ideal profile) and raw ping-pong through the router."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    keys = SwarmKeys("lab")
    # Logins as in a run, but no access control: the bench itself plays robot1 and robot2
    # and pings on keys of its own.
    credentials_dir = Path(tempfile.mkdtemp()) / "credentials"
    credentials = generate_credential_set("lab", ("robot1", "robot2", "robot3"))
    files = write_credential_set(credentials_dir, credentials)
    document = router_config_document(credentials, credentials_dir / "router-users.txt", [endpoint])
    document["access_control"]["enabled"] = False
    router_config = credentials_dir / "router.json5"
    write_private_file(router_config, json.dumps(document).encode())
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "router",
            "--listen",
            endpoint,
            "--config",
            str(router_config),
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    world = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "world",
            "--scenario",
            "configs/scenarios/paper.yaml",
            "--connect",
            endpoint,
            "--radio",
            "ideal",
            "--credentials",
            str(files["world"]),
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        with open_client([endpoint], credentials=read_credentials(files["operator"])) as session:
            got = threading.Event()
            arrived: list[int] = []

            def on_rx(sample) -> None:  # type: ignore[no-untyped-def]
                arrived.append(time.perf_counter_ns())
                got.set()

            session.declare_subscriber(keys.radio_rx("robot2"), on_rx)
            echo = session.declare_subscriber(
                "bench/ping", lambda s: session.put("bench/pong", s.payload.to_bytes())
            )
            session.declare_subscriber("bench/pong", on_rx)
            time.sleep(2.0)

            def measure(key: str) -> list[float]:
                out = []
                for k in range(samples):
                    got.clear()
                    start = time.perf_counter_ns()
                    session.put(key, k.to_bytes(8, "little") * 11)
                    if got.wait(1.0):
                        out.append((arrived[-1] - start) / 1e6)
                    time.sleep(0.005)
                return out

            measure(keys.radio_tx("robot1"))  # warm up
            radio = measure(keys.radio_tx("robot1"))
            raw = measure("bench/ping")
            echo.undeclare()
            return radio, raw
    finally:
        for p in (world, router):
            p.terminate()
            p.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--samples", type=int, default=500)
    args = parser.parse_args()
    print("# networked swarm runtime")
    for line in machine_lines():
        print(line)
    print(f"# paper scenario, 3 robots; median of {args.runs} runs")
    print()
    speedups = [lockstep_speedup(10.0) for _ in range(args.runs)]
    print(
        f"lockstep speed-up over real time: {statistics.median(speedups):.2f}x "
        f"(runs: {', '.join(f'{s:.2f}' for s in speedups)}; goal 10x)"
    )
    print()
    timings, cpus = zip(*(realtime_run() for _ in range(args.runs)), strict=True)
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
    print()
    radio, raw = one_hop_latency_ms(args.samples)
    print(f"{'path (ideal profile)':<42} {'p50 ms':>7} {'p99 ms':>7} {'n':>5}")
    for label, values in (
        ("robot1 -> world -> robot2 (radio hop)", radio),
        ("raw zenoh ping-pong via the router", raw),
    ):
        print(
            f"{label:<42} {np.percentile(values, 50):>7.3f} "
            f"{np.percentile(values, 99):>7.3f} {len(values):>5}"
        )


if __name__ == "__main__":
    main()

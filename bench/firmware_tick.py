"""Cost of the robot firmware's control tick (not a test: prints a table).

Runs the paper scenario with every robot as firmware on its fabric model (no network), and
measures the wall time of `Firmware.control_tick` of the leader, with the compiled control
step and with the numpy oracle (tests/control/oracle.py) in the same run.  Where the time goes
is measured too: the control step (levels 2-4) and the bus accesses (reads and writes through
the drivers, levels 1 and 5) are timed inside the tick; the rest is the firmware's own Python
(trajectory, inputs, frame encoding).  Median over repetitions; machine and date printed.

A robot process runs the kernels compiled ahead of time (SWARM_KERNELS=aot, no numba in the
process: robot_firmware/control/kernels.py).  The control steps of the leader's measured ticks
are recorded and replayed in a child process of that kind, next to a child with the JIT on the
same steps; each child also reports what importing the robot process's modules costs in memory
(VmRSS: ru_maxrss would count the parent's pages from before the exec).

The tick above runs the register model and drivers from their source (SWARM_NATIVE=python, as
this process imports them).  A robot process runs them compiled by mypyc (robot_firmware/
native.py): two more children run the leader's whole tick each way, interleaved, on the same
scenario.

    .venv/bin/python bench/firmware_tick.py [--ticks 1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import os
import pickle
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from arguments import positive_int
from machine import machine_lines
from oracle_paths import PATHS, control_path

from robot_firmware.control.controller import OneRobotControl
from robot_firmware.net.frames import key_from_secret
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


REPLAY = """
import pickle, statistics, sys, time
import robot_firmware.runtime
from robot_firmware.control import kernels
from robot_firmware.control.controller import OneRobotControl
status = open("/proc/self/status").read()
imports_mib = int(status.split("VmRSS:")[1].split()[0]) / 1024
params, peers, rules, steps = pickle.loads(sys.stdin.buffer.read())
control = OneRobotControl(params, peers, rules)
spent = []
for _ in range(3):
    for state, inputs, role, t_s, fresh in steps:
        control.load(state)
        for name, value in inputs.items():
            getattr(control.inputs, name)[...] = value
        for name, value in role.items():
            getattr(control.role, name)[...] = value
        start = time.perf_counter()
        control.step(t_s, fresh)
        spent.append(time.perf_counter() - start)
print(kernels.MODE, "numba" in sys.modules, imports_mib, statistics.median(spent) * 1e6)
"""


def _replay(setup: tuple[Any, ...], steps: list[tuple[Any, ...]], mode: str) -> dict[str, float]:
    """Median control step (us) over `steps` and RSS after the imports (MiB), in a child."""
    ran = subprocess.run(
        [sys.executable, "-c", REPLAY],
        input=pickle.dumps((*setup, steps)),
        capture_output=True,
        env={**os.environ, "SWARM_KERNELS": mode},
        cwd=ROOT,
        check=True,
    )
    got_mode, numba_loaded, imports_mib, step_us = ran.stdout.decode().split()
    if got_mode != mode:
        raise SystemExit(f"wanted {mode} kernels, the child ran {got_mode}: {ran.stderr.decode()}")
    return {
        "step_us": float(step_us),
        "imports_mib": float(imports_mib),
        "numba_loaded": float(numba_loaded == "True"),
    }


REGISTER_MODEL = """
import statistics, sys, time
from pathlib import Path
from robot_firmware import native
from robot_firmware.net.frames import key_from_secret
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.scenario import load_scenario
ticks = int(sys.argv[1])
swarm = FirmwareSwarm(load_scenario(Path("configs/scenarios/paper.yaml")), key_from_secret("bench"))
for _ in range(50):
    swarm.step()
firmware = swarm.robots[0].firmware
original_tick = firmware.control_tick
spent = []
def timed_tick(now_ns):
    start = time.perf_counter()
    report = original_tick(now_ns)
    spent.append(time.perf_counter() - start)
    return report
firmware.control_tick = timed_tick
for _ in range(ticks):
    swarm.step()
spent.sort()
print(native.MODE, statistics.median(spent) * 1e6, spent[int(0.99 * (len(spent) - 1))] * 1e6)
"""
REGISTER_MODES = ("python", "mypyc")


def _register_model_tick(ticks: int, mode: str) -> dict[str, float]:
    """The leader's control tick (median and p99, us) in a child running the register model
    and drivers one way (SWARM_NATIVE); the control step on numba's JIT, which the world engine
    of the firmware swarm needs in the process."""
    ran = subprocess.run(
        [sys.executable, "-c", REGISTER_MODEL, str(ticks)],
        capture_output=True,
        env={**os.environ, "SWARM_NATIVE": mode},
        cwd=ROOT,
        check=True,
    )
    got_mode, median_us, p99_us = ran.stdout.decode().split()
    if got_mode != mode:
        raise SystemExit(
            f"wanted the register model {mode}, the child ran {got_mode} "
            f"(python -m robot_firmware.native_build builds it): {ran.stderr.decode()}"
        )
    return {"median_us": float(median_us), "p99_us": float(p99_us)}


def _snapshot(control: OneRobotControl, t_s: float, sonar_fresh: bool) -> tuple[Any, ...]:
    """What one control step starts from: its state, inputs and role (copies), time, sweep."""
    state = copy.deepcopy(control.state)
    inputs = {
        f.name: np.array(getattr(control.inputs, f.name))
        for f in dataclasses.fields(control.inputs)
        if f.name not in ("t_s", "sonar_fresh")
    }
    role = {
        f.name: np.array(getattr(control.role, f.name)) for f in dataclasses.fields(control.role)
    }
    return state, inputs, role, t_s, sonar_fresh


def _measure(ticks: int, path: str) -> dict[str, float]:
    scenario = load_scenario(ROOT / "configs/scenarios/paper.yaml")
    with control_path(path):
        swarm = FirmwareSwarm(scenario, key_from_secret("bench"))
        for _ in range(50):  # boot, localise, first frames, compile
            swarm.step()
        robot = swarm.robots[0]
        bus = robot.fabric.bus
        firmware = robot.firmware
        tick_s: list[float] = []
        spent = {"control_step": 0.0, "bus": 0.0, "in_leader": 0.0}
        original_tick = firmware.control_tick
        control = firmware.control
        original_step = control.step
        original_read, original_write = bus.read_word, bus.write_word
        recorded: list[tuple[Any, ...]] = []

        def timed_tick(now_ns: int) -> Any:
            spent["in_leader"] = 1.0
            start = time.perf_counter()
            report = original_tick(now_ns)
            tick_s.append(time.perf_counter() - start)
            spent["in_leader"] = 0.0
            return report

        def timed_step(t_s: float, sonar_fresh: bool) -> Any:
            if spent["in_leader"] and path == "compiled":
                recorded.append(_snapshot(control, t_s, sonar_fresh))
            start = time.perf_counter()
            result = original_step(t_s, sonar_fresh)
            spent["control_step"] += (time.perf_counter() - start) * spent["in_leader"]
            return result

        def timed_read(address: int) -> Any:  # the drivers' word accesses (RegisterPort)
            start = time.perf_counter()
            result = original_read(address)
            spent["bus"] += time.perf_counter() - start
            return result

        def timed_write(address: int, value: int) -> Any:
            start = time.perf_counter()
            result = original_write(address, value)
            spent["bus"] += time.perf_counter() - start
            return result

        firmware.control_tick = timed_tick  # type: ignore[method-assign]
        reads0, writes0 = bus.read_count, bus.write_count
        for _ in range(ticks):
            swarm.step()
        reads = (bus.read_count - reads0) / ticks
        writes = (bus.write_count - writes0) / ticks
        # The breakdown, in a second pass (the timers themselves cost a little).
        control.step = timed_step  # type: ignore[method-assign]
        bus.read_word, bus.write_word = timed_read, timed_write  # type: ignore[method-assign]
        timed_ticks = tick_s[:]
        tick_s.clear()
        for _ in range(ticks):
            swarm.step()
        breakdown_total = sum(tick_s)
        control.step = original_step  # type: ignore[method-assign]
        bus.read_word, bus.write_word = original_read, original_write  # type: ignore[method-assign]
    replayed = {}
    if path == "compiled":
        # The same steps, first here (JIT), then in a robot process's kind of child (aot).
        setup = (control.params, len(scenario.robots), firmware.rules)
        aot = _replay(setup, recorded, "aot")
        jit_child = _replay(setup, recorded, "jit")
        replayed = {
            "replay_jit_us": jit_child["step_us"],
            "replay_aot_us": aot["step_us"],
            "imports_aot_mib": aot["imports_mib"],
            "imports_jit_mib": jit_child["imports_mib"],
            "numba_in_aot": aot["numba_loaded"],
        }
    return {
        **replayed,
        "tick_median_us": float(np.median(timed_ticks)) * 1e6,
        "tick_p99_us": float(np.percentile(timed_ticks, 99)) * 1e6,
        "control_step_us": spent["control_step"] / ticks * 1e6,
        "bus_us": spent["bus"] / ticks * 1e6,
        "rest_us": (breakdown_total - spent["control_step"] - spent["bus"]) / ticks * 1e6,
        "reads": reads,
        "writes": writes,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=positive_int, default=1000)
    parser.add_argument("--repeats", type=positive_int, default=3)
    args = parser.parse_args()
    rows: dict[str, list[dict[str, float]]] = {path: [] for path in PATHS}
    register_rows: dict[str, list[dict[str, float]]] = {mode: [] for mode in REGISTER_MODES}
    for _ in range(args.repeats):
        for path in PATHS:
            rows[path].append(_measure(args.ticks, path))
        for mode in REGISTER_MODES:
            register_rows[mode].append(_register_model_tick(args.ticks, mode))
    median = {
        path: {k: statistics.median(r[k] for r in rows[path]) for k in rows[path][0]}
        for path in PATHS
    }
    print("# firmware control tick: compiled control step vs the numpy oracle")
    for line in machine_lines():
        print(line)
    print(f"# paper scenario, leader robot, {args.ticks} ticks x {args.repeats} runs (median)")
    print()
    print(f"{'':34}{'compiled':>10}{'oracle':>10}")
    labels = (
        ("control_tick median (us)", "tick_median_us"),
        ("control_tick p99 (us)", "tick_p99_us"),
        ("  control step, levels 2-4 (us)", "control_step_us"),
        ("  bus accesses, levels 1 and 5 (us)", "bus_us"),
        ("  rest of the tick (us)", "rest_us"),
        ("bus reads per tick", "reads"),
        ("bus writes per tick", "writes"),
    )
    for label, key in labels:
        print(f"{label:34}{median['compiled'][key]:>10.1f}{median['oracle'][key]:>10.1f}")
    compiled = median["compiled"]
    print()
    print("# the leader's control steps replayed in child processes: numba's JIT, and the")
    print("# ahead-of-time module as a robot runs it (SWARM_KERNELS=aot)")
    print(f"{'':34}{'jit':>10}{'aot':>10}")
    print(
        f"{'control step, median (us)':34}{compiled['replay_jit_us']:>10.1f}"
        f"{compiled['replay_aot_us']:>10.1f}"
    )
    print(
        f"{'robot modules imported, RSS MiB':34}{compiled['imports_jit_mib']:>10.1f}"
        f"{compiled['imports_aot_mib']:>10.1f}"
    )
    print(f"numba imported by the aot child: {'yes' if compiled['numba_in_aot'] else 'no'}")
    with_aot_us = compiled["tick_median_us"] - compiled["replay_jit_us"] + compiled["replay_aot_us"]
    print(f"control_tick median with the aot step (estimate): {with_aot_us:.1f} us")
    print()
    print("# the leader's whole tick in child processes (JIT control step): the register model")
    print("# and drivers from source, and compiled by mypyc as a robot runs them")
    print(f"{'':34}{'source':>10}{'mypyc':>10}{'ratio':>10}")
    for label, key in (
        ("control_tick median (us)", "median_us"),
        ("control_tick p99 (us)", "p99_us"),
    ):
        source_us, compiled_us = (
            statistics.median(r[key] for r in register_rows[mode]) for mode in REGISTER_MODES
        )
        print(f"{label:34}{source_us:>10.1f}{compiled_us:>10.1f}{compiled_us / source_us:>10.2f}")
    print()
    print("goal: control_tick median at most 100 us (compiled); budget at 100 Hz 10000 us")


if __name__ == "__main__":
    main()

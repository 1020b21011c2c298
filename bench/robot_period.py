"""A robot process's main-thread work per control period, without the network (prints tables).

The robot processes of a wedge of N robots (`RobotProcess`, exactly as `swarm robot` builds
them, but never connected) run in one process against the world engine, in a closed loop: each
period the world's sense messages are encoded as the world encodes them and queued on each
robot as its subscriber would queue them; the radio frames due are queued too; then each robot
does what its main loop does for a tick (`_take_sense`, the scheduler's decision, `_run_period`:
fabric, frames, the 5C control tick, act and telemetry messages) with publishers that keep the
payloads; the acts go back to the world, the frames onto its radio medium.  Only the robots'
work is timed, phase by phase.

Two cache conditions, in the same run:

* **warm**: the robots run back to back, as in a tight loop;
* **cold**: before each robot's period, a sweep over a buffer larger than the last-level cache
  evicts what the robot touched last time, as when a dozen other processes ran on the core in
  the 10 ms since its last tick (what `bench/robot_phases.py` sees in a running swarm).

The warm figures repeat to a few per cent on a quiet machine, the cold ones to about 15 %
(each run prints its total); `bench/robot_phases.py` and `bench/scale.py` say what a change is
worth in a running swarm.

The register model and drivers run as a robot runs them: compiled by mypyc when the build for
their sources is there (robot_firmware/native.py); `SWARM_NATIVE=python` in the environment runs
them from source, for a comparison (the header says which).

    .venv/bin/python bench/robot_period.py [--robots 12] [--periods 1500] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from arguments import positive_int  # noqa: E402
from machine import machine_lines  # noqa: E402

os.environ.setdefault("SWARM_NATIVE", "mypyc")  # as `swarm up` starts a robot
from robot_firmware import native  # noqa: E402
from robot_firmware.net.wire import WireDropReason, encode_sense_rows, parse_act  # noqa: E402
from robot_firmware.runtime import RobotConfig, RobotProcess  # noqa: E402
from robot_firmware.tick_scheduler import RunTick  # noqa: E402
from swarm_config.credentials import generate_credential_set, write_credential_set  # noqa: E402
from swarm_config.generate import GenerateRequest, generate_scenario_text  # noqa: E402
from swarm_config.scenario import load_scenario  # noqa: E402
from tests.fuzz.processes import KeptPublisher  # noqa: E402
from world.engine import WorldEngine  # noqa: E402

WARM_UP_PERIODS = 300
EVICT_BYTES = 64 << 20
"""Larger than this machine's last-level cache share (an EPYC CCX has 16-32 MiB)."""
PHASES = ("sense", "fabric", "frames", "control_tick", "act", "telemetry", "rest")
NESTED = {"control_step": "control_tick"}
"""Phases timed inside another (not added to `rest`): the compiled control step, levels 2-4."""
LABELS = {
    "sense": "sense message to the pins",
    "fabric": "fabric model's period",
    "frames": "radio frames received",
    "control_tick": "5C control tick",
    "control_step": ". of it the control step",
    "act": "act message",
    "telemetry": "telemetry (20 Hz)",
    "rest": "the rest (scheduler, loop)",
    "all": "all of it",
}


class PhaseClock:
    """Wraps methods of one robot so that each call adds its wall time to a phase."""

    def __init__(self) -> None:
        self.spent_ns = dict.fromkeys((*PHASES, *NESTED), 0)

    def wrap(self, owner: Any, method: str, phase: str) -> None:
        original = getattr(owner, method)
        spent = self.spent_ns
        clock = time.perf_counter_ns

        def timed(*args: Any, **kwargs: Any) -> Any:
            started = clock()
            try:
                return original(*args, **kwargs)
            finally:
                spent[phase] += clock() - started

        setattr(owner, method, timed)


def build(robots: int, work: Path) -> tuple[WorldEngine, list[RobotProcess]]:
    scenario_path = work / f"wedge-{robots}.yaml"
    scenario_path.write_text(
        generate_scenario_text(GenerateRequest(robots=robots, formation="wedge", seed=1)),
        encoding="utf-8",
    )
    scenario = load_scenario(scenario_path)
    names = scenario.robot_names
    credentials = write_credential_set(work / "credentials", generate_credential_set("lab", names))
    world = WorldEngine(scenario, seed=1)
    processes = []
    for name in names:
        config = RobotConfig.model_validate(
            {"name": name, "scenario": scenario_path, "credentials": credentials[name]}
        )
        process = RobotProcess(config)
        process.firmware.boot(process._tick_fabric)
        processes.append(process)
    return world, processes


@dataclass
class PeriodOut:
    """What each robot did in one closed-loop period: its main-loop wall time and what it put."""

    elapsed_ns: list[int]
    sense: list[bytes]
    act: list[bytes]
    frames: list[list[bytes]]
    telemetry: list[list[bytes]]


def closed_loop_period(
    world: WorldEngine,
    processes: list[RobotProcess],
    period: int,
    before_robot: Callable[[], None] | None = None,
) -> PeriodOut:
    """One control period of every robot against the world: the due frames and the encoded
    sense messages queued as the subscribers would queue them, each robot's main-loop work for
    a tick (timed; `before_robot` runs first, untimed), its act applied and its frames put on
    the radio medium, then the world's physics step."""
    robots = len(processes)
    out = PeriodOut([0] * robots, [], [], [[] for _ in processes], [[] for _ in processes])
    delivered = [0] * robots
    for receiver, _sender, payload in world.due_frames():
        processes[receiver]._frames.append(payload)
        delivered[receiver] += 1
    out.sense = encode_sense_rows(world.sense_pins(), period, True, delivered, 0)
    duty = np.zeros((robots, 4))
    act_pub, tx_pub, telemetry_pub = KeptPublisher(), KeptPublisher(), KeptPublisher()
    for index, (process, payload) in enumerate(zip(processes, out.sense, strict=True)):
        if before_robot is not None:
            before_robot()
        started = time.perf_counter_ns()
        process._sense.append((payload, time.monotonic_ns()))
        process._take_sense()
        decision = process.scheduler.poll(time.monotonic_ns(), len(process._frames))
        if not isinstance(decision, RunTick):
            raise SystemExit(f"{process.config.name} did not tick at period {period}")
        process._run_period(decision, act_pub, tx_pub, telemetry_pub)
        process.scheduler.finished(decision, time.monotonic_ns())
        out.elapsed_ns[index] = time.perf_counter_ns() - started
        out.act.append(act_pub.payloads.pop())
        act = parse_act(out.act[-1])
        if isinstance(act, WireDropReason):
            raise SystemExit(f"{process.config.name} sent an act the world drops: {act}")
        duty[index] = np.where(act.enabled, act.duty, 0.0)
        for frame in tx_pub.payloads:
            world.transmit(index, frame)
        out.frames[index] = tx_pub.payloads[:]
        out.telemetry[index] = telemetry_pub.payloads[:]
        tx_pub.payloads.clear()
        telemetry_pub.payloads.clear()
    world.advance(duty, processes[0].period_ns)
    return out


def run(robots: int, periods: int, cold: bool, work: Path) -> dict[str, float]:
    """Median over robots of the mean µs per period of each phase."""
    world, processes = build(robots, work)
    clocks = []
    for process in processes:
        clock = PhaseClock()
        clock.wrap(process, "_take_sense", "sense")
        clock.wrap(process, "_advance_fabric_to", "fabric")
        clock.wrap(process.firmware, "receive", "frames")
        clock.wrap(process.firmware, "control_tick", "control_tick")
        clock.wrap(process.firmware.control, "step", "control_step")
        clock.wrap(process, "_publish_act", "act")
        clock.wrap(process, "_publish_telemetry", "telemetry")
        clocks.append(clock)
    evict = np.zeros(EVICT_BYTES // 8)

    def sweep() -> None:
        nonlocal evict
        evict += 1.0

    totals_ns = [0] * robots
    for period in range(WARM_UP_PERIODS + periods):
        if period == WARM_UP_PERIODS:
            for clock in clocks:
                clock.spent_ns.update(dict.fromkeys(clock.spent_ns, 0))
            totals_ns = [0] * robots
        out = closed_loop_period(world, processes, period, sweep if cold else None)
        totals_ns = [t + e for t, e in zip(totals_ns, out.elapsed_ns, strict=True)]
    result = {}
    for phase in (*PHASES[:-1], *NESTED):
        result[phase] = statistics.median(c.spent_ns[phase] for c in clocks) / periods / 1e3
    result["all"] = statistics.median(totals_ns) / periods / 1e3
    result["rest"] = result["all"] - sum(result[p] for p in PHASES[:-1])
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--robots", type=positive_int, default=12, help="robots in the wedge (default 12)"
    )
    parser.add_argument(
        "--periods", type=positive_int, default=1500, help="measured periods (1500)"
    )
    parser.add_argument("--repeats", type=positive_int, default=3, help="runs per condition (3)")
    args = parser.parse_args(argv)
    results: dict[str, list[dict[str, float]]] = {"warm": [], "cold": []}
    with tempfile.TemporaryDirectory(prefix="robot-period-") as tmp:
        for repeat in range(args.repeats):
            for condition in ("warm", "cold"):
                work = Path(tmp) / f"{condition}-{repeat}"
                work.mkdir()
                results[condition].append(run(args.robots, args.periods, condition == "cold", work))
    print("# a robot's main-thread work per control period, no network")
    for line in machine_lines():
        print(line)
    print(
        f"# {args.robots}-robot wedge, {args.periods} periods after {WARM_UP_PERIODS} of "
        f"warm-up, median over robots, median of {args.repeats} runs"
    )
    how = "compiled (mypyc)" if native.MODE == "mypyc" else "from source"
    print(f"# register model and drivers: {how}")
    print()
    print(f"{'phase (us per control period)':32}{'warm':>10}{'cold':>10}{'cold/warm':>11}")
    rows = list(PHASES)
    rows.insert(rows.index("control_tick") + 1, "control_step")
    for phase in (*rows, "all"):
        warm = statistics.median(r[phase] for r in results["warm"])
        cold = statistics.median(r[phase] for r in results["cold"])
        ratio = f"{cold / warm:.2f}" if warm > 0.5 else ""
        print(f"{LABELS[phase]:32}{warm:10.1f}{cold:10.1f}{ratio:>11}")
    for condition, runs in results.items():
        spread = ", ".join(f"{r['all']:.0f}" for r in runs)
        print(f"# {condition}: all of it per run (us): {spread}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

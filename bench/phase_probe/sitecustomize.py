"""Per-phase CPU probe for `bench/robot_phases.py`: loaded by every Python process of a `swarm
up` whose PYTHONPATH starts with this directory, active only where $SWARM_PHASE_PROBE_DIR is
set and the process is a robot or the world.

It wraps the methods of the robot's and the world's main loops named below so that each call
adds the calling thread's CPU time (`time.thread_time_ns`) to its phase, and writes the totals
to $SWARM_PHASE_PROBE_DIR/<role>-<pid>.json every 250 periods.  The first `WARM_UP_PERIODS`
periods (start-up, first contact) are dropped.  Phases nest as the code does: `_control`
holds `control_tick`, `receive`, `_publish_act` and `_publish_telemetry`.  A wrapped call
costs two reads of the thread's CPU clock more (the script prints what one costs).  The cyclic
garbage collector's runs are timed too (`gc.callbacks`), per generation, as phases of their own.
"""

from __future__ import annotations

import gc
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

WARM_UP_PERIODS = 1500
DUMP_EVERY_PERIODS = 250

ROBOT_PHASES = {
    "robot_firmware.runtime:RobotProcess": (
        "_take_sense",
        "_serve_queries",
        "_run_period",
        "_control",
        "_advance_fabric_to",
        "_publish_act",
        "_publish_telemetry",
    ),
    "robot_firmware.firmware:Firmware": ("control_tick", "receive"),
    "robot_firmware.tick_scheduler:TickScheduler": ("poll",),
}
WORLD_PHASES = {
    "world.runtime:WorldProcess": (
        "_drain",
        "_braked_duty",
        "_publish_sense",
        "_deliver_radio",
        "_pass_frames_on",
        "_publish_truth",
        "_checkpoint_if_due",
    ),
    "world.engine:WorldEngine": ("advance", "record_metrics", "transmit", "sense_pins"),
}


def _install(phases: dict[str, tuple[str, ...]], counter: tuple[str, str], role: str) -> None:
    import importlib

    out = Path(os.environ["SWARM_PHASE_PROBE_DIR"])
    clock = time.thread_time_ns
    totals: dict[str, list[int]] = {}
    state = {"periods": 0, "main_thread_at_reset_ns": 0}

    def wrap(cls: Any, name: str) -> None:
        original = getattr(cls, name)
        cell = totals.setdefault(f"{cls.__name__}.{name}", [0, 0])

        def timed(*args: Any, **kwargs: Any) -> Any:
            started = clock()
            try:
                return original(*args, **kwargs)
            finally:
                cell[0] += clock() - started
                cell[1] += 1

        setattr(cls, name, timed)

    for where, names in phases.items():
        module_name, class_name = where.split(":")
        cls = getattr(importlib.import_module(module_name), class_name)
        for name in names:
            wrap(cls, name)

    def dump() -> None:
        record = {
            "role": role,
            "argv": sys.argv,
            "periods": state["periods"] - WARM_UP_PERIODS,
            "main_thread_ns": clock() - state["main_thread_at_reset_ns"],
            "phases": totals,
        }
        path = out / f"{role}-{os.getpid()}.json"
        path.with_suffix(".tmp").write_text(json.dumps(record))
        path.with_suffix(".tmp").replace(path)

    def on_collection(phase: str, info: dict[str, int]) -> None:
        """The cyclic collector's own CPU, per generation, on whichever thread triggered it."""
        if phase == "start":
            state["gc_started_ns"] = clock()
            return
        cell = totals.setdefault(f"gc.collect (generation {info['generation']})", [0, 0])
        cell[0] += clock() - state.get("gc_started_ns", clock())
        cell[1] += 1

    gc.callbacks.append(on_collection)

    module_name, qualified = counter
    class_name, method = qualified.split(".")
    cls = getattr(importlib.import_module(module_name), class_name)
    original: Callable[..., Any] = getattr(cls, method)

    def counted(*args: Any, **kwargs: Any) -> Any:
        state["periods"] += 1
        if state["periods"] == WARM_UP_PERIODS:
            for cell in totals.values():
                cell[0] = cell[1] = 0
            state["main_thread_at_reset_ns"] = clock()
        elif state["periods"] > WARM_UP_PERIODS and state["periods"] % DUMP_EVERY_PERIODS == 0:
            dump()
        return original(*args, **kwargs)

    setattr(cls, method, counted)


if os.environ.get("SWARM_PHASE_PROBE_DIR"):
    if "robot" in sys.argv[1:3]:
        _install(ROBOT_PHASES, ("robot_firmware.tick_scheduler", "TickScheduler.finished"), "robot")
    elif "world" in sys.argv[1:3]:
        _install(WORLD_PHASES, ("world.runtime", "WorldProcess._publish_sense"), "world")

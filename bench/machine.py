"""The machine and date a benchmark ran on, printed above every table of bench/.

The same 2-core virtual machine runs the same code up to 1.7 times slower from one hour to the
next (docs/scale.md): the header also times a fixed calibration workload, the kind of work a
robot's period is made of (a pure-Python loop of small calls, NumPy calls on 3-element arrays,
and random reads over 64 MiB, more than a core's caches hold, as when a dozen processes share
them), so figures of different hours can be put side by side by it.  Lower is faster."""

from __future__ import annotations

import datetime as dt
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> str:
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:
        return "n/a"
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


CALIBRATION_CALLS = 100_000
CALIBRATION_REPEATS = 5
CALIBRATION_TABLE_WORDS = 16 << 20
"""64 MiB of 32-bit words."""
CALIBRATION_READS = 1 << 20


def _python_calls() -> None:
    def step(value: int, gain: int) -> int:
        return (value * gain + 1) & 0xFFFF

    value = 1
    for i in range(CALIBRATION_CALLS):
        value = step(value, i)


def _small_numpy_calls() -> None:
    pose = np.zeros(3)
    rate = np.array([0.1, 0.2, 0.3])
    for _ in range(CALIBRATION_CALLS // 10):
        pose += rate * 0.01
        np.hypot(pose[0], pose[1])


def _random_reads() -> Callable[[], None]:
    rng = np.random.default_rng(1)
    table = np.arange(CALIBRATION_TABLE_WORDS, dtype=np.int32)
    where = rng.integers(0, table.size, CALIBRATION_READS)

    def read() -> None:
        table[where].sum()

    return read


def host_speed_ms() -> dict[str, float]:
    """Milliseconds the calibration workloads take here now (median of a few runs)."""
    speeds = {}
    workloads = (
        ("python", _python_calls),
        ("numpy", _small_numpy_calls),
        ("memory", _random_reads()),
    )
    for name, work in workloads:
        times = []
        for _ in range(CALIBRATION_REPEATS):
            started = time.perf_counter()
            work()
            times.append(1e3 * (time.perf_counter() - started))
        speeds[name] = statistics.median(times)
    return speeds


def machine_lines() -> list[str]:
    """Header lines: date and time, CPU, cores, load, Python and NumPy versions, and how fast
    the host runs the calibration workloads now."""
    speed = host_speed_ms()
    return [
        f"# {dt.datetime.now().astimezone().isoformat(timespec='seconds')}",
        f"# machine: {cpu_model()}, {os.cpu_count()} cores, load average {load_average()}",
        f"# Python {platform.python_version()}, NumPy {np.__version__}, {platform.platform()}",
        f"# host speed now (bench/machine.py calibration, lower is faster): "
        f"{speed['python']:.1f} ms of Python calls, {speed['numpy']:.1f} ms of small NumPy calls, "
        f"{1e6 * speed['memory'] / CALIBRATION_READS:.1f} ns per random read over 64 MiB",
    ]


def machine_record() -> dict[str, object]:
    """The same facts for a JSON results file."""
    return {
        "date": dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "load_average": load_average(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "host_speed_ms": host_speed_ms(),
    }

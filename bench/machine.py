"""The machine and date a benchmark ran on, printed above every table of bench/."""

from __future__ import annotations

import datetime as dt
import os
import platform
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


def machine_lines() -> list[str]:
    """Header lines: date and time, CPU, cores, load, Python and NumPy versions."""
    return [
        f"# {dt.datetime.now().astimezone().isoformat(timespec='seconds')}",
        f"# machine: {cpu_model()}, {os.cpu_count()} cores, load average {load_average()}",
        f"# Python {platform.python_version()}, NumPy {np.__version__}, {platform.platform()}",
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
    }

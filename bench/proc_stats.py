"""What a process costs, read from /proc (Linux): CPU seconds, resident and proportional memory.

* `cpu_seconds(pid)`: user + system time, from /proc/PID/stat (fields 14 and 15);
* `rss_mib(pid)`: resident set (VmRSS of /proc/PID/status), `peak_rss_mib` its high-water mark
  (VmHWM); shared pages (Python, NumPy, numba's LLVM) count in full in every process;
* `pss_mib(pid)`: proportional set size (/proc/PID/smaps_rollup): shared pages divided among the
  processes that map them, so the PSS of N robots adds up to what they cost together;
* `CpuWindow`: % of one core per process over a window;
* `descendants(pid)`: every live process below a process (children of children included).

A process that is gone gives None, never an exception.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")
KIB_PER_MIB = 1024.0


def cpu_seconds(pid: int) -> float | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()  # the command name may hold spaces and ')'
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def _status_kib(pid: int, key: str, file: str = "status") -> float | None:
    try:
        text = Path(f"/proc/{pid}/{file}").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith(key + ":"):
            return float(line.split()[1])
    return None


def rss_mib(pid: int) -> float | None:
    kib = _status_kib(pid, "VmRSS")
    return None if kib is None else kib / KIB_PER_MIB


def peak_rss_mib(pid: int) -> float | None:
    kib = _status_kib(pid, "VmHWM")
    return None if kib is None else kib / KIB_PER_MIB


def pss_mib(pid: int) -> float | None:
    kib = _status_kib(pid, "Pss", "smaps_rollup")
    return None if kib is None else kib / KIB_PER_MIB


def descendants(pid: int) -> list[int]:
    """Every live process below `pid`, parents before their children."""
    found: list[int] = []
    pending = [pid]
    while pending:
        parent = pending.pop(0)
        try:
            tasks = list(Path(f"/proc/{parent}/task").iterdir())
        except OSError:
            continue
        for task in tasks:
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for child in map(int, children):
                if child not in found:
                    found.append(child)
                    pending.append(child)
    return found


class CpuWindow:
    """% of one core each process used between `CpuWindow(pids)` and `percent()`."""

    def __init__(self, pids: Mapping[str, int]) -> None:
        self.pids = dict(pids)
        self._started_s = time.monotonic()
        self._before = {name: cpu_seconds(pid) for name, pid in self.pids.items()}

    def percent(self) -> dict[str, float | None]:
        wall_s = time.monotonic() - self._started_s
        out: dict[str, float | None] = {}
        for name, pid in self.pids.items():
            before, now = self._before[name], cpu_seconds(pid)
            out[name] = None if before is None or now is None else 100.0 * (now - before) / wall_s
        return out


def memory_mib(pids: Mapping[str, int]) -> dict[str, tuple[float | None, float | None]]:
    """(RSS, PSS) of each process now, MiB."""
    return {name: (rss_mib(pid), pss_mib(pid)) for name, pid in pids.items()}


def alive(pids: Iterable[int]) -> list[int]:
    return [pid for pid in pids if Path(f"/proc/{pid}").exists()]

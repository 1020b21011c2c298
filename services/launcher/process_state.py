"""What the kernel says of a process: its state letter in /proc/PID/stat, and whether that is
a stop (the launcher's status, and the command line's word on a launcher that does not
answer)."""

from __future__ import annotations

from pathlib import Path

STOPPED_STATES = ("T", "t")
"""/proc/PID/stat states of a stopped process: by a signal, or by a debugger."""


def process_state(pid: int) -> str | None:
    """The state letter of /proc/PID/stat (R, S, D, T, t, Z, ...), None where it cannot be
    read (not Linux, the process gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 1 :].split()  # the name in parentheses may hold spaces
    return fields[0] if fields else None

"""The open files the router of a swarm on one host needs, checked before anything starts.

The router holds two sockets per connected process (the launcher, the world, every robot, the
dashboard, each `swarm` command while it runs) and a few of its own: 36 descriptors for 14
processes, 60 for 26.  Zenoh raises each process's soft limit to its hard limit by itself, so
the hard limit (`ulimit -Hn`) is what counts.  Under `ulimit -n 32`, a 12-robot `swarm up`
started every process, and the router, out of descriptors, let no more of them in without a
word: the world and some robots waited for it until Ctrl-C, and the run had no summary.  The
launcher now refuses such a start in one line, naming the limit.
"""

from __future__ import annotations

import resource

ROUTER_FILES_PER_CLIENT = 2
"""Descriptors the router holds per connected process."""
ROUTER_BASE_FILES = 8
"""What the router holds before anyone connects."""
SPARE_CLIENTS = 4
"""Connections beyond the launcher's own processes: `swarm` commands, a second dashboard."""


def router_files_needed(clients: int) -> int:
    """Descriptors a router with `clients` connected processes needs, with room for a few
    more."""
    return ROUTER_FILES_PER_CLIENT * (clients + SPARE_CLIENTS) + ROUTER_BASE_FILES


def open_file_limit_problem(needed: int) -> str | None:
    """Why a process of this one's limits cannot hold `needed` open files, or None."""
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or hard >= needed:
        return None
    return f"this shell allows {hard} open files (`ulimit -Hn`), and the router needs {needed}"

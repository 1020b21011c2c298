"""Paths given on a command line as the empty string.

Python's paths take `''` for the current folder (`Path('') == Path('.')`), so `swarm up --out
''` (a variable that was never set, `--out "$RUN"`) wrote a whole run, credentials included,
into whatever folder the user stood in, and `swarm credentials ''` its secrets.  Every command
refuses an empty path argument before it does anything; `.` still names the current folder.
"""

from __future__ import annotations

import argparse
import errno
import os
from pathlib import Path

PATH_ARGUMENTS = {
    "out": "--out",
    "scenario": "--scenario",
    "config": "--config",
    "credentials": "--credentials",
    "dir": "DIR",
    "file": "FILE",
    "recording": "FILE.rrd",
}
"""Destination -> the flag or placeholder the user knows, for every path argument of the
`swarm` commands."""


def empty_path_problem(args: argparse.Namespace) -> str | None:
    """What is wrong when a path argument of `args` is the empty string, else None."""
    for destination, flag in PATH_ARGUMENTS.items():
        if getattr(args, destination, None) == "":
            return f"{flag} is an empty path (write . for the current folder)"
    return None


def broken_link_problem(path: Path) -> str | None:
    """What `path` is when it is a symbolic link that leads to nothing (pathlib's exists()
    says False, mkdir "File exists", open "No such file"): one to a missing target, or a loop
    of links; else None."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return f"{path} is a symbolic link in a loop of links, which leads to no file"
        if os.path.islink(path):
            return f"{path} is a symbolic link to {os.readlink(path)}, which does not exist"
    return None

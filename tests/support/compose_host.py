"""Host-side chores of scripts/compose-smoke.sh that need Python, as one command line.

    python -m tests.support.compose_host port [--prefer PORT]
    python -m tests.support.compose_host requirements PYPROJECT
    python -m tests.support.compose_host wheel-member WHEEL SUFFIX DEST
    python -m tests.support.compose_host wait-http URL [--timeout S]

`port` prints PORT when 127.0.0.1:PORT can be bound, else a free port the kernel picks;
`requirements` prints the runtime dependencies of a pyproject.toml, one a line;
`wheel-member` copies the one member of a wheel whose name ends with SUFFIX to DEST;
`wait-http` waits until URL answers HTTP at all. Exit status 0 on success, 1 with an
"ERROR: ..." line otherwise, 2 for a usage error.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import sys
import tomllib
import urllib.error
import urllib.request
import zipfile
from collections.abc import Sequence
from pathlib import Path

from tests.support.waiting import wait_for


class HostError(Exception):
    """A chore that could not be done; the message says what."""


def port_is_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_port(prefer: int | None = None) -> int:
    """`prefer` when it can be bound on 127.0.0.1, else a port the kernel picks."""
    if prefer is not None and port_is_free(prefer):
        return prefer
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def runtime_requirements(pyproject: Path) -> list[str]:
    try:
        with pyproject.open("rb") as f:
            project = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise HostError(f"cannot read {pyproject}: {exc}") from exc
    dependencies = project.get("project", {}).get("dependencies")
    if not isinstance(dependencies, list) or not all(isinstance(d, str) for d in dependencies):
        raise HostError(f"{pyproject} has no [project] dependencies list")
    return dependencies


def extract_wheel_member(wheel: Path, suffix: str, dest: Path) -> str:
    """Copies the one member whose name ends with `suffix` to `dest`; returns its name."""
    try:
        with zipfile.ZipFile(wheel) as archive:
            members = [n for n in archive.namelist() if n.endswith(suffix)]
            if len(members) != 1:
                raise HostError(f"{wheel} has {len(members)} members ending with {suffix!r}")
            with archive.open(members[0]) as src, dest.open("wb") as dst:
                shutil.copyfileobj(src, dst)
    except (OSError, zipfile.BadZipFile) as exc:
        raise HostError(f"cannot extract {suffix!r} from {wheel}: {exc}") from exc
    return members[0]


def http_status(url: str, timeout_s: float) -> int | None:
    """The HTTP status of a GET of `url` (also 4xx, 5xx); None when nothing answers."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            return int(response.status)
    except urllib.error.HTTPError as exc:
        return exc.code
    except (OSError, ValueError):
        return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.support.compose_host",
        description="Host-side chores of scripts/compose-smoke.sh.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    port = sub.add_parser("port", help="print a free TCP port on 127.0.0.1")
    port.add_argument("--prefer", type=int, help="this port if it is free")
    reqs = sub.add_parser("requirements", help="print the runtime dependencies of a pyproject")
    reqs.add_argument("pyproject", type=Path)
    member = sub.add_parser("wheel-member", help="copy one member of a wheel to a file")
    member.add_argument("wheel", type=Path)
    member.add_argument("suffix", help="the end of the member's name")
    member.add_argument("dest", type=Path)
    http = sub.add_parser("wait-http", help="wait until a URL answers HTTP")
    http.add_argument("url")
    http.add_argument("--timeout", type=float, default=5.0, help="seconds (default 5)")
    args = parser.parse_args(argv)
    try:
        if args.command == "port":
            print(free_port(args.prefer))
        elif args.command == "requirements":
            print("\n".join(runtime_requirements(args.pyproject)))
        elif args.command == "wheel-member":
            extract_wheel_member(args.wheel, args.suffix, args.dest)
        else:
            wait_for(
                lambda: http_status(args.url, timeout_s=1.0) is not None,
                args.timeout,
                0.1,
                describe=f"an HTTP answer from {args.url}",
            )
    except (HostError, AssertionError) as exc:
        print(f"ERROR: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

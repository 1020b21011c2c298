"""`python -m services.dashboard dashboard|replay ...`: the subcommands without `swarm`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from services.dashboard.cli import add_dashboard_parsers
from services.log_setup import LogLevelError, set_up_logging
from services.path_arguments import empty_path_problem


def main(argv: Sequence[str] | None = None) -> int:
    try:
        set_up_logging()
    except LogLevelError as exc:
        print(f"python -m services.dashboard: {exc}", file=sys.stderr)
        return 2
    parser = argparse.ArgumentParser(
        prog="python -m services.dashboard",
        description="Live Rerun dashboard of a swarm, and replay of its recordings.",
    )
    add_dashboard_parsers(parser.add_subparsers(dest="command", metavar="COMMAND"))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    empty_path = empty_path_problem(args)
    if empty_path is not None:
        print(f"python -m services.dashboard {args.command}: {empty_path}", file=sys.stderr)
        return 2
    code: int = args.handler(args)
    return code


if __name__ == "__main__":
    sys.exit(main())

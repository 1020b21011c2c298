"""`python -m services.dashboard dashboard|replay ...`: the subcommands without `swarm`."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence

from services.dashboard.cli import add_dashboard_parsers


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(
        level=os.environ.get("SWARM_LOG_LEVEL", "INFO"),
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    parser = argparse.ArgumentParser(
        prog="python -m services.dashboard",
        description="Live Rerun dashboard of a swarm, and replay of its recordings.",
    )
    add_dashboard_parsers(parser.add_subparsers(dest="command", metavar="COMMAND"))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    code: int = args.handler(args)
    return code


if __name__ == "__main__":
    sys.exit(main())

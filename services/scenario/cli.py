"""`swarm scenario generate`: write a scenario file for a formation of N robots.

    swarm scenario generate --robots N [--formation wedge|line|grid] [--spacing-m S]
        [--trajectory circle|lemniscate|polyline] [--size-m M] [--speed-mps V]
        [--obstacles K] [--seed S] [--duration S] [--name NAME] --out FILE

The generator and its rules (slots at least 2 body radii + the APF influence distance apart,
initial poses that do not overlap) are in :mod:`swarm_config.generate`.  The file is parsed
back and checked before it is written; equal arguments give byte-identical files.  A mistake
raises :class:`~swarm_config.generate.ScenarioGenerationError` (a ScenarioError): the `swarm`
command prints it in one line and exits with status 2, and no file is written.
"""

from __future__ import annotations

import argparse
import stat
import sys
from pathlib import Path
from typing import Any, NoReturn

from swarm_config.atomic_files import FileWriteError, write_file_atomically
from swarm_config.generate import (
    FORMATIONS,
    MAX_ROBOTS,
    SPACING_MARGIN_M,
    TRAJECTORIES,
    TRAJECTORY_DEFAULTS,
    GenerateRequest,
    ScenarioGenerationError,
    generate_scenario_text,
)

EXIT_USAGE = 2


class OneLineErrorParser(argparse.ArgumentParser):
    """An argument parser whose mistakes are one line on stderr and exit status 2."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {message} (see --help)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _cmd_generate(args: argparse.Namespace) -> int:
    request = GenerateRequest(
        robots=args.robots,
        formation=args.formation,
        spacing_m=args.spacing_m,
        trajectory=args.trajectory,
        size_m=args.size_m,
        speed_mps=args.speed_mps,
        obstacles=args.obstacles,
        seed=args.seed,
        duration_s=args.duration,
        name=args.name,
    )
    text = generate_scenario_text(request)
    out = Path(args.out)
    refuse_unusable_destination(out)
    if not args.force and out.is_file() and out.read_bytes() != text.encode("utf-8"):
        raise ScenarioGenerationError(
            f"--out {out} exists and holds another scenario; give --force to replace it, or "
            "another file name"
        )
    write_text_file(out, text)
    robots = "1 robot" if request.robots == 1 else f"{request.robots} robots"
    print(f"wrote {args.out} ({robots}, {request.formation})")
    return 0


def refuse_unusable_destination(path: Path) -> None:
    """ScenarioGenerationError unless `path` is absent or a regular file: the write renames a
    new file over it, which would replace a device node (as root, `--out /dev/null` deleted
    the system's /dev/null), a FIFO or a socket, or a symbolic link (dangling or not), with a
    regular file."""
    if path.is_dir():
        raise ScenarioGenerationError(f"--out {path} is a directory; give a file name")
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise ScenarioGenerationError(f"cannot write {path} ({exc.strerror})") from None
    if stat.S_ISLNK(mode):
        raise ScenarioGenerationError(
            f"--out {path} is a symbolic link; give the file itself or another file name"
        )
    if not stat.S_ISREG(mode):
        raise ScenarioGenerationError(
            f"--out {path} exists and is not a regular file; give another file name"
        )


def write_text_file(path: Path, text: str) -> None:
    """Write `text` to `path` through a temporary file and a rename: a failed write leaves
    whatever was there before."""
    refuse_unusable_destination(path)
    if not path.parent.is_dir():
        raise ScenarioGenerationError(f"cannot write {path} (no folder {path.parent})")
    try:
        write_file_atomically(path, text.encode("utf-8"))
    except FileWriteError as exc:
        raise ScenarioGenerationError(f"cannot write {path} ({exc.strerror})") from None


def add_scenario_parser(sub: Any) -> None:
    """`swarm scenario generate` on the `swarm` command's subparsers."""
    scenario = sub.add_parser(
        "scenario",
        help="write scenario files (swarm scenario generate --robots N ...)",
        description="Write scenario files. `swarm scenario generate --help` for the options.",
    )
    actions = scenario.add_subparsers(
        dest="scenario_action", metavar="ACTION", parser_class=OneLineErrorParser
    )
    scenario.set_defaults(handler=lambda _args: _print_help(scenario))
    generate = actions.add_parser(
        "generate",
        help="a scenario with a formation of N robots",
        description=(
            "Write a scenario file with one leader and N - 1 followers in a wedge, a line "
            "abreast or a grid, collision-free at rest: slots are at least 2 body radii + the "
            "APF influence distance apart (no repulsion between robots at their slots), initial "
            "poses lie 0.3-0.6 spacings from the slots without overlapping. The leader's path "
            "is sized so the formation fits. The file is validated before it is written; equal "
            "arguments give byte-identical files."
        ),
    )
    generate.add_argument(
        "--robots", type=int, required=True, metavar="N", help=f"robots, 1..{MAX_ROBOTS}"
    )
    generate.add_argument("--formation", choices=FORMATIONS, default="wedge")
    generate.add_argument(
        "--spacing-m",
        type=float,
        metavar="S",
        help=f"distance between neighbouring slots (default: 2 body radii + APF influence + "
        f"{SPACING_MARGIN_M} m = 1.2 m, the paper's triangle)",
    )
    generate.add_argument("--trajectory", choices=TRAJECTORIES, default="circle")
    generate.add_argument(
        "--size-m",
        type=float,
        metavar="M",
        help="circle radius, lemniscate amplitude or half the square's side (default: "
        + ", ".join(f"{k} {v.size_m} m" for k, v in TRAJECTORY_DEFAULTS.items())
        + ", or the formation's extent when larger)",
    )
    generate.add_argument(
        "--speed-mps",
        type=float,
        metavar="V",
        help="the leader's path speed, the lemniscate's peak speed (default: "
        + ", ".join(f"{k} {v.speed_mps:g}" for k, v in TRAJECTORY_DEFAULTS.items())
        + ")",
    )
    generate.add_argument(
        "--obstacles", type=int, default=1, metavar="K", help="obstacles on the path (default: 1)"
    )
    generate.add_argument(
        "--seed", type=int, default=0, help="scenario seed and initial poses (default: 0)"
    )
    generate.add_argument(
        "--duration", type=float, default=60.0, metavar="S", help="duration_s (default: 60)"
    )
    generate.add_argument("--name", help="scenario name (default: FORMATION-N)")
    generate.add_argument(
        "--out",
        required=True,
        metavar="FILE",
        help="scenario file to write; an existing file is replaced only with --force (or when "
        "it holds exactly what this command writes); anything else that is there (a device, "
        "a FIFO, a symbolic link) is refused",
    )
    generate.add_argument(
        "--force", action="store_true", help="replace --out even if it holds another scenario"
    )
    generate.set_defaults(handler=_cmd_generate)


def _print_help(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return EXIT_USAGE

"""What a `swarm` command loads before it runs: the operator's commands (status, kill, fault,
regs, ...) start without the scenario models, the control kernels, numba or the tuner, and
`swarm --help` and a mistyped command still see every subcommand."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY_MODULES = ("numba", "llvmlite", "scipy", "world", "services.tuner", "swarm_config.scenario")

LOADED_AFTER_PARSING = """
import sys
import services.cli.main as cli
parser = cli.build_parser({command!r})
args = parser.parse_args({argv!r})
loaded = [m for m in {heavy!r} if m in sys.modules]
print(args.command, ",".join(loaded) or "-")
"""


def _loaded_after_parsing(command: str | None, argv: list[str]) -> list[str]:
    code = LOADED_AFTER_PARSING.format(command=command, argv=argv, heavy=HEAVY_MODULES)
    ran = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert ran.returncode == 0, ran.stderr
    return ran.stdout.split()


@pytest.mark.parametrize(
    "argv",
    [
        ["status"],
        ["kill", "robot2"],
        ["regs", "robot1", "0xFF200000"],
        ["net", "get"],
        ["fault", "kill", "robot2"],
        ["robot", "--name", "robot1"],
    ],
)
def test_operator_commands_parse_without_the_heavy_modules(argv: list[str]) -> None:
    assert _loaded_after_parsing(argv[0], argv) == [argv[0], "-"]


def test_the_heavy_commands_get_their_parsers() -> None:
    command, loaded = _loaded_after_parsing("tune", ["tune", "--scenario", "s.yaml", "--out", "o"])
    assert command == "tune"
    assert "services.tuner" in loaded.split(",")


def test_help_and_a_mistyped_command_list_every_subcommand() -> None:
    listed = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert listed.returncode == 0
    for command in ("status", "fault", "tune", "dashboard", "scenario", "replay"):
        assert command in listed.stdout
    mistyped = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "stauts"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert mistyped.returncode == 2
    assert "invalid choice: 'stauts'" in mistyped.stderr and "'tune'" in mistyped.stderr

"""`$SWARM_LOG_LEVEL` (services/log_setup.py): a level by name, or one line and status 2."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.log_setup import LogLevelError, log_level_from

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("given", "level"),
    [(None, "INFO"), ("", "INFO"), ("  ", "INFO"), ("debug", "DEBUG"), (" Warning ", "WARNING")],
)
def test_a_level_is_taken_by_name_in_any_case_and_unset_is_info(
    given: str | None, level: str
) -> None:
    assert log_level_from({} if given is None else {"SWARM_LOG_LEVEL": given}) == level


@pytest.mark.parametrize("given", ["bogus", "10", "INFOO", "warn"])
def test_anything_else_is_refused_naming_the_variable_and_the_levels(given: str) -> None:
    with pytest.raises(LogLevelError, match=r"\$SWARM_LOG_LEVEL=.* use one of DEBUG, INFO"):
        log_level_from({"SWARM_LOG_LEVEL": given})


@pytest.mark.parametrize(
    "argv",
    [
        ["-m", "services.cli.main", "status", "--connect", "tcp/127.0.0.1:9"],
        ["-m", "services.dashboard", "dashboard"],
    ],
)
def test_a_command_with_a_bad_level_stops_in_one_line_before_it_starts(argv: list[str]) -> None:
    result = subprocess.run(
        [sys.executable, *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "SWARM_LOG_LEVEL": "bogus"},
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "$SWARM_LOG_LEVEL='bogus' is not a log level" in lines[0], lines

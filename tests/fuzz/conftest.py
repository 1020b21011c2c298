"""Fuzz tests: the session ends with a table of inputs generated and refusals per reason."""

from __future__ import annotations

import pytest

from tests.fuzz.ledger import LEDGER
from tests.fuzz.processes import robot_credentials


@pytest.fixture(scope="session", autouse=True)
def _robots_have_credentials(tmp_path_factory: pytest.TempPathFactory) -> None:
    robot_credentials(tmp_path_factory.mktemp("credentials"))


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not LEDGER.outcomes:
        return
    terminalreporter.section("fuzzing: generated inputs and refusals per reason")
    for line in LEDGER.table():
        terminalreporter.write_line(line)

"""The default scenario is the project's own file from whatever folder a command runs in."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from swarm_config.scenario import DEFAULT_SCENARIO_PATH, load_scenario


def test_the_default_scenario_is_the_projects_paper_experiment() -> None:
    assert DEFAULT_SCENARIO_PATH.is_absolute()
    assert load_scenario(DEFAULT_SCENARIO_PATH).name == "paper"


def test_a_command_run_outside_the_project_finds_the_default_scenario(tmp_path: Path) -> None:
    # Before, `swarm up` (or any command taking the default) run from another folder said
    # "configs/scenarios/paper.yaml: cannot read scenario file".
    made = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "credentials", "set"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert made.returncode == 0, made.stderr
    written = {path.name for path in (tmp_path / "set").iterdir()}
    assert {"robot1.json", "robot2.json", "robot3.json", "world.json"} <= written

"""`swarm sim` on scenarios it cannot run as written: a fault campaign it does not apply is
said on stderr; a rate too slow for its tick counters is refused before any folder is made."""

import json
from pathlib import Path

import pytest
import yaml

from services.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def _paper_with(tmp_path: Path, **changes: object) -> Path:
    data = yaml.safe_load(PAPER.read_text(encoding="utf-8"))
    data.update(changes)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_a_fault_campaign_gets_one_warning_line_naming_swarm_up(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, the campaign was dropped without a word: every robot "killed" at t = 1 s, and the
    # summary showed a healthy formation.
    faults = [{"at_s": 1.0, "fault": {"fault": "kill", "process": f"robot{i}"}} for i in (1, 2)]
    scenario = _paper_with(tmp_path, faults=faults)
    out = tmp_path / "run"
    argv = ["sim", "--scenario", str(scenario), "--out", str(out), "--duration", "2"]
    assert main([*argv, "--no-figures", "--no-compare"]) == 0
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "does not apply this scenario's faults (2 scheduled faults)" in lines[0]
    assert "`swarm up` (or `swarm up --lockstep`) runs the campaign" in lines[0]
    assert "warning" not in captured.out
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["events"] == []
    # A scenario without faults runs as before: nothing on stderr.
    argv = ["sim", "--scenario", str(PAPER), "--out", str(tmp_path / "paper"), "--duration", "1"]
    assert main([*argv, "--no-figures", "--no-compare"]) == 0
    assert capsys.readouterr().err == ""


def test_a_tune_of_a_scenario_with_faults_warns_once_that_they_are_not_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`swarm tune` evaluates candidates in the batch simulator, which runs no faults either."""
    faults = [{"at_s": 0.5, "fault": {"fault": "kill", "process": "robot2"}}]
    scenario = _paper_with(tmp_path, faults=faults)
    argv = ["tune", "--scenario", str(scenario), "--out", str(tmp_path / "tune")]
    assert main([*argv, "--algo", "pso", "--budget", "20", "--duration", "1.0"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "faults" in line]
    assert warnings == [
        "swarm tune: warning: the batch simulator does not apply this scenario's faults "
        "(1 scheduled fault); it runs without them. `swarm up` (or `swarm up --lockstep`) runs "
        "the campaign"
    ]


@pytest.mark.parametrize(
    ("section", "value", "named"),
    [
        ("radio", {"profile": "lab", "broadcast_rate_hz": 1e-17}, "radio.broadcast_rate_hz"),
        ("sensors", {"sonar": {"rate_hz": 1e-17}}, "sensors.sonar.rate_hz"),
        ("sensors", {"positioning": {"rate_hz": 1e-17}}, "sensors.positioning.rate_hz"),
    ],
)
def test_a_rate_too_slow_is_refused_naming_the_field_and_makes_no_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], section: str, value: object, named: str
) -> None:
    # Before: OverflowError from services/sim/batch.py, status 1.
    scenario = _paper_with(tmp_path, **{section: value})
    out = tmp_path / "run"
    argv = ["sim", "--scenario", str(scenario), "--out", str(out), "--duration", "1"]
    try:
        status = main([*argv, "--no-figures"])
    except SystemExit as exc:
        status = exc.code  # type: ignore[assignment]
    assert status == 2
    assert f"{named}: Input should be greater than or equal to 0.01" in capsys.readouterr().err
    assert not out.exists()

"""The batch simulator and `swarm sim` on the paper's scenario."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.cli.main import main
from services.sim.batch import run_batch
from swarm_config.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _swarm(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli.main", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("paper")
    assert main(["sim", "--scenario", str(PAPER), "--out", str(out)]) == 0
    return out, json.loads((out / "summary.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["fuzzy_scheduled_pid", "fixed_gain_pid"])
def test_paper_scenario_meets_the_tracking_and_safety_bounds(
    paper_run: tuple[Path, dict], controller: str
) -> None:
    _, summary = paper_run
    result = summary["comparison"][controller]
    assert result["leader_tracking_rms_m"] <= 0.02
    assert set(result["formation_rms_m"]) == {"robot2", "robot3"}
    for value in result["formation_rms_m"].values():
        assert value <= 0.03
    assert result["collisions"] == 0
    assert result["min_obstacle_clearance_m"] > 0.0
    assert result["min_robot_separation_m"] > 0.0


@pytest.mark.slow
def test_summary_holds_the_documented_keys_and_the_figures_exist(
    paper_run: tuple[Path, dict],
) -> None:
    out, summary = paper_run
    for key in (
        "scenario",
        "seed",
        "duration_s",
        "leader_tracking_rms_m",
        "leader_tracking_rms_all_m",
        "leader_heading_rms_rad",
        "formation_rms_m",
        "formation_rms_all_m",
        "formation_max_m",
        "nominal_share",
        "min_robot_separation_m",
        "min_obstacle_clearance_m",
        "collisions",
        "fitness_snr_db",
        "radio",
    ):
        assert key in summary, key
    assert summary["scenario"] == "paper" and summary["seed"] == 7
    assert summary["controller"] == "fuzzy_scheduled_pid"
    assert (
        summary["leader_tracking_rms_m"]
        == summary["comparison"]["fuzzy_scheduled_pid"]["leader_tracking_rms_m"]
    )
    # Avoidance manoeuvres are excluded from the nominal figures but not from the _all ones.
    assert summary["leader_tracking_rms_all_m"] > summary["leader_tracking_rms_m"]
    assert 0.0 < summary["nominal_share"]["robot1"] < 1.0
    assert summary["radio"]["frames_delivered"] <= 2 * summary["radio"]["frames_sent"]
    for name in ("fig11_paths", "fig12_leader_tracking_error", "fig13_formation_errors"):
        data = (out / f"{name}.png").read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 20_000


@pytest.mark.slow
def test_same_seed_gives_byte_identical_summary(tmp_path: Path) -> None:
    runs = []
    for name, seed in (("a", "7"), ("b", "7"), ("c", "8")):
        result = _swarm(
            "sim",
            "--scenario",
            str(PAPER),
            "--out",
            str(tmp_path / name),
            "--no-figures",
            "--seed",
            seed,
            "--duration",
            "25",
        )
        assert result.returncode == 0, result.stderr
        runs.append((tmp_path / name / "summary.json").read_bytes())
    assert runs[0] == runs[1]
    assert runs[0] != runs[2]


def test_bad_scenario_exits_2_naming_the_field_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(PAPER.read_text().replace("radius_m: 0.15", "radius_m: -0.15"))
    result = _swarm("sim", "--scenario", str(bad), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert "obstacles.0.radius_m" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists()
    missing = _swarm("sim", "--scenario", str(tmp_path / "nope.yaml"), "--out", str(tmp_path))
    assert missing.returncode == 2 and "cannot read" in missing.stderr


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (("--duration", "-5"), "duration_s: Input should be greater than 0"),
        (("--duration", "inf"), "duration_s: Input should be a finite number"),
        (("--duration", "nan"), "duration_s: Input should be a finite number"),
        (("--seed", "-1", "--duration", "1"), "seed: Input should be greater than or equal to 0"),
        (("--duration", "0.001"), "duration_s (0.001 s) is shorter than one control period"),
    ],
)
def test_bad_command_line_values_exit_2_naming_the_field(
    tmp_path: Path, flags: tuple[str, ...], named: str
) -> None:
    result = _swarm("sim", "--scenario", str(PAPER), "--out", str(tmp_path / "out"), *flags)
    assert result.returncode == 2, result.stderr
    assert named in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists()


def test_help_lists_the_sim_command() -> None:
    result = _swarm("--help")
    assert result.returncode == 0
    assert "sim" in result.stdout
    sim_help = _swarm("sim", "--help")
    assert "--scenario" in sim_help.stdout and "summary.json" in sim_help.stdout


def test_batch_elements_equal_separate_runs_under_shared_noise() -> None:
    scenario = load_scenario(PAPER)
    table2 = FuzzyRuleBase.table2()
    coarse = FuzzyRuleBase.table2(3, 3)
    batch = run_batch(
        scenario,
        3,
        FuzzyRuleBase.stack([table2, coarse, table2]),
        shared_noise=True,
        duration_s=4.0,
        record_trace=True,
    )
    alone = run_batch(scenario, 1, coarse, shared_noise=True, duration_s=4.0, record_trace=True)
    assert batch.trace is not None and alone.trace is not None
    poses = batch.trace.arrays()["true_pose"]
    np.testing.assert_array_equal(poses[:, 1], alone.trace.arrays()["true_pose"][:, 0])
    np.testing.assert_array_equal(poses[:, 0], poses[:, 2])
    assert not np.array_equal(poses[:, 0], poses[:, 1])
    np.testing.assert_array_equal(batch.rule_count, [147, 27, 147])


def test_independent_noise_differs_across_the_batch() -> None:
    scenario = load_scenario(PAPER)
    result = run_batch(scenario, 2, duration_s=2.0, record_trace=True)
    assert result.trace is not None
    poses = result.trace.arrays()["true_pose"]
    assert not np.array_equal(poses[-1, 0], poses[-1, 1])

"""`swarm tune`: outputs robots can load, monotone convergence, exact resume, clear errors."""

import argparse
import json
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from services.tuner import fuzzy_tuning
from services.tuner.cli import TuneArgumentError, add_tune_parser, parse_algorithms, run_tune
from services.tuner.evaluation import FloatArray, Objective
from services.tuner.fitness import evaluation_scenario
from services.tuner.fuzzy_tuning import read_convergence_csv, read_settings
from swarm_config.scenario import (
    Scenario,
    ScenarioError,
    load_fuzzy_parameters,
    load_rule_base,
    load_scenario,
)

ROOT = Path(__file__).resolve().parents[3]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TINY = ["--budget", "90", "--duration", "1.0"]


def tune_args(*args: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="swarm")
    add_tune_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["tune", *args])


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tune")
    args = tune_args("--scenario", str(PAPER), "--out", str(out), "--algo", "ofa,pso", *TINY)
    assert args.handler is run_tune
    assert run_tune(args) == 0
    return out


def test_best_fuzzy_file_is_loadable_by_robots_and_scenarios(tiny_run: Path) -> None:
    best = tiny_run / "best_fuzzy.yaml"
    parameters = load_fuzzy_parameters(best)
    assert 2 <= len(parameters.error_centres) <= 7
    scenario_file = tiny_run / "tuned.yaml"
    scenario_file.write_text(
        PAPER.read_text(encoding="utf-8") + "\nfuzzy_parameter_file: best_fuzzy.yaml\n",
        encoding="utf-8",
    )
    rule_base = load_rule_base(load_scenario(scenario_file))
    assert int(rule_base.rule_count) == len(parameters.error_centres) * len(parameters.rate_centres)
    summary = json.loads((tiny_run / "tune.json").read_text(encoding="utf-8"))
    winner = summary["results"][summary["best_algorithm"]]
    assert winner["best_fuzzy"] == parameters.model_dump(exclude_none=True)
    assert winner["recomputed_best_cost"] == winner["best_cost"]


def test_convergence_csv_never_gets_worse_and_spends_the_budget(tiny_run: Path) -> None:
    rows = read_convergence_csv(tiny_run / "convergence.csv")
    assert {row["algorithm"] for row in rows} == {"ofa", "pso"}
    for algorithm in ("ofa", "pso"):
        mine = [row for row in rows if row["algorithm"] == algorithm]
        cost = np.array([float(row["best_cost"]) for row in mine])
        evaluations = np.array([int(row["evaluations"]) for row in mine])
        fitness_db = np.array([float(row["best_fitness_db"]) for row in mine])
        assert len(mine) >= 3
        assert np.all(np.diff(cost) <= 0.0)
        assert np.all(np.diff(evaluations) > 0) and evaluations[-1] == 90
        np.testing.assert_allclose(fitness_db, -10.0 * np.log10(cost))
    assert (tiny_run / "convergence.png").read_bytes().startswith(PNG_MAGIC)


def test_progress_line_shows_generation_evaluations_best_and_rate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = tune_args("--scenario", str(PAPER), "--out", str(tmp_path), "--algo", "ga", *TINY)
    assert run_tune(args) == 0
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.startswith("tune ga")]
    assert len(lines) >= 3
    assert all("evals" in line and "dB" in line and "evals/s" in line for line in lines)
    assert "gen   0" in lines[0] and "90/90" in lines[-1]
    assert "wall time" in captured.out


def _interrupt_after(calls: int, monkeypatch: pytest.MonkeyPatch) -> None:
    real = fuzzy_tuning.make_objective

    def interrupting(scenario: Scenario, **kwargs: Any) -> Objective:
        inner = real(scenario, **kwargs)
        count = [0]

        def objective(x: FloatArray) -> FloatArray:
            count[0] += 1
            if count[0] > calls:
                raise KeyboardInterrupt
            return inner(x)

        return objective

    monkeypatch.setattr(fuzzy_tuning, "make_objective", interrupting)


def _outputs(out: Path) -> tuple[str, str, str]:
    return (
        (out / "ofa" / "convergence.csv").read_text(encoding="utf-8"),
        (out / "ofa" / "best_fuzzy.yaml").read_text(encoding="utf-8"),
        (out / "best_fuzzy.yaml").read_text(encoding="utf-8"),
    )


def test_resume_after_an_interruption_gives_the_uninterrupted_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    budget = ["--budget", "130", "--duration", "1.0"]
    whole = tmp_path / "whole"
    assert run_tune(tune_args("--scenario", str(PAPER), "--out", str(whole), *budget)) == 0

    split = tmp_path / "split"
    with monkeypatch.context() as patch:
        _interrupt_after(2, patch)
        status = run_tune(tune_args("--scenario", str(PAPER), "--out", str(split), *budget))
    assert status == 130
    assert (split / "ofa" / "checkpoint.npz").exists()
    assert not (split / "best_fuzzy.yaml").exists()
    resumed = run_tune(
        tune_args("--scenario", str(PAPER), "--out", str(split), "--resume", *budget)
    )
    assert resumed == 0
    assert _outputs(split) == _outputs(whole)


def test_existing_run_without_resume_or_with_other_settings_is_refused(tiny_run: Path) -> None:
    again = tune_args("--scenario", str(PAPER), "--out", str(tiny_run), "--algo", "ofa", *TINY)
    with pytest.raises(ValueError, match="--resume"):
        run_tune(again)
    clash = tune_args("--scenario", str(PAPER), "--out", str(tiny_run), "--algo", "fa,ofa", *TINY)
    with pytest.raises(ValueError, match="--resume"):
        run_tune(clash)
    assert not (tiny_run / "fa").exists()  # refused before the first algorithm started
    other = tune_args(
        "--scenario",
        str(PAPER),
        "--out",
        str(tiny_run),
        "--algo",
        "ofa",
        "--resume",
        "--budget",
        "91",
        "--duration",
        "1.5",
    )
    with pytest.raises(ValueError, match="budget"):
        run_tune(other)


@pytest.mark.parametrize(
    ("extra", "error", "message"),
    [
        (["--algo", "sa"], ValueError, "unknown algorithm 'sa'.*fa, ga, ofa, pso"),
        (["--algo", "ofa,ofa"], ValueError, "twice"),
        (["--budget", "0"], ValueError, "budget"),
        (["--seed", "-1"], ValueError, "seed"),
        (["--duration", "-2"], ValueError, "duration"),
    ],
)
def test_bad_flags_give_clear_errors(
    tmp_path: Path, extra: list[str], error: type[Exception], message: str
) -> None:
    args = tune_args("--scenario", str(PAPER), "--out", str(tmp_path), *extra)
    with pytest.raises(error, match=message):
        run_tune(args)
    assert not any(tmp_path.iterdir())


def test_missing_scenario_is_a_scenario_error(tmp_path: Path) -> None:
    args = tune_args("--scenario", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "out"))
    with pytest.raises(ScenarioError, match=r"nope\.yaml"):
        run_tune(args)


def test_swarm_command_reports_a_bad_flag_in_one_line_with_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from services.cli.main import main

    status = main(["tune", "--scenario", str(PAPER), "--out", str(tmp_path), "--algo", "sa"])
    assert status == 2
    error = capsys.readouterr().err
    assert "unknown algorithm 'sa'" in error and "Traceback" not in error


def test_algorithm_lists_are_parsed_in_order() -> None:
    assert parse_algorithms("OFA, ga,pso") == ["ofa", "ga", "pso"]
    check: Callable[[str], list[str]] = parse_algorithms
    with pytest.raises(ValueError, match="one or more"):
        check(" , ")


@pytest.mark.parametrize(
    "stored",
    ["{", "[1]", '{"algorithm": "ofa"}', "[" * 100_000 + "]" * 100_000],
    ids=["cut short", "not an object", "not every setting", "nested too deep"],
)
def test_a_run_json_that_is_not_settings_reads_as_none(tmp_path: Path, stored: str) -> None:
    path = tmp_path / "run.json"
    path.write_text(stored, encoding="utf-8")
    assert read_settings(path) is None  # resume then refuses it as unreadable, in one line


def _swarm_tune_child(out: Path, *extra: str) -> subprocess.Popen[str]:
    """`swarm tune` as a user starts it, with Ctrl-C acting as in a terminal."""
    argv = [sys.executable, "-m", "services.cli.main", "tune", "--scenario", str(PAPER)]
    return subprocess.Popen(
        [*argv, "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def test_ctrl_c_pressed_again_while_tune_winds_down_gives_no_traceback(tmp_path: Path) -> None:
    # Before, a second Ctrl-C while the batch simulator's threads finished their step
    # interrupted the interpreter's exit with a traceback (and status -2 instead of 130).
    child = _swarm_tune_child(tmp_path, "--budget", "100000", "--duration", "30")
    assert child.stdout is not None
    output: list[str] = []
    for line in child.stdout:  # the first generation: the batch simulator's threads are busy
        output.append(line)
        if line.startswith("tune ofa gen"):
            break
    child.send_signal(signal.SIGINT)
    deadline_s = time.monotonic() + 120.0  # generous: a loaded machine winds down slowly
    while child.poll() is None and time.monotonic() < deadline_s:
        child.send_signal(signal.SIGINT)  # as a user pressing Ctrl-C again and again
        time.sleep(0.01)
    output.append(child.communicate(timeout=30)[0])
    text = "".join(output)
    assert child.returncode == 130, text
    assert "interrupted: ofa is checkpointed in" in text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text


def test_a_second_tune_in_the_folder_of_a_running_one_is_refused(tmp_path: Path) -> None:
    # Before, both ran and wrote each other's checkpoints and results.
    first = _swarm_tune_child(tmp_path, "--budget", "100000", "--duration", "30")
    assert first.stdout is not None
    try:
        for line in first.stdout:
            if line.startswith("tune ofa gen"):
                break
        args = tune_args("--scenario", str(PAPER), "--out", str(tmp_path), "--algo", "ga", *TINY)
        with pytest.raises(TuneArgumentError) as refused:
            run_tune(args)
        assert (
            f"{tmp_path} is the output folder of another `swarm tune` that is still running "
            f"(pid {first.pid})"
        ) in str(refused.value)
        assert not (tmp_path / "ga").exists()
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=120)
    assert first.returncode == 130


def _change_field(checkpoint: Path, field: str, value: Callable[[Any], Any]) -> None:
    """Rewrite one field of a checkpoint archive, as someone editing it by hand would."""
    with np.load(checkpoint, allow_pickle=False) as archive:
        fields = {key: archive[key] for key in archive.files}
    fields[field] = value(fields[field])
    with checkpoint.open("wb") as handle:
        np.savez(handle, **fields)


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("positions", lambda a: a[:, :5], "positions: shape"),
        ("rng_state", lambda a: np.array('{"bit_generator": "PCG64", "state": 1}'), "rng_state"),
    ],
)
def test_resume_from_a_checkpoint_with_a_field_changed_is_one_line_and_status_2(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    field: str,
    value: Callable[[Any], Any],
    named: str,
) -> None:
    out = tmp_path / "tune"
    assert run_tune(tune_args("--scenario", str(PAPER), "--out", str(out), *TINY)) == 0
    checkpoint = out / "ofa" / "checkpoint.npz"
    _change_field(checkpoint, field, value)
    best_before = (out / "best_fuzzy.yaml").read_bytes()
    capsys.readouterr()
    resume = tune_args("--scenario", str(PAPER), "--out", str(out), "--resume", *TINY)
    try:
        status = run_tune(resume)
    except ValueError as exc:  # refused before the run: the swarm command prints it, status 2
        status, said = 2, str(exc)
    else:
        said = capsys.readouterr().err
    assert status == 2
    assert f"{checkpoint} is damaged ({named}" in said, said
    assert (out / "best_fuzzy.yaml").read_bytes() == best_before


@pytest.fixture(scope="module")
def finished_ofa_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("finished") / "tune"
    assert run_tune(tune_args("--scenario", str(PAPER), "--out", str(out), *TINY)) == 0
    return out


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("best_cost", lambda a: np.array(np.inf), "best_cost: inf"),
        ("best_cost", lambda a: np.array(0.0), "best_cost: 0.0"),
        ("generation", lambda a: np.array([1, 2]), "generation: shape (2,)"),
        ("history_best_cost", lambda a: a * 0.0, "history_best_cost: "),
        (
            "rng_state",
            lambda a: np.array(
                '{"bit_generator": "PCG64", "state": {"state": -1, "inc": 1}, '
                '"has_uint32": 0, "uinteger": 0}'
            ),
            "rng_state: not a PCG64 state",
        ),
        ("history_n_evaluations", lambda a: a * 0 - 5, "history_n_evaluations: "),
    ],
)
def test_resume_from_a_checkpoint_with_a_value_no_run_writes_is_one_line_and_status_2(
    tmp_path: Path,
    finished_ofa_run: Path,
    field: str,
    value: Callable[[Any], Any],
    named: str,
) -> None:
    # Before: a traceback (best_cost, generation, history_best_cost, rng_state), or a resume
    # that wrote convergence rows with -5 evaluations (history_n_evaluations).
    out = tmp_path / "tune"
    shutil.copytree(finished_ofa_run, out)
    checkpoint = out / "ofa" / "checkpoint.npz"
    _change_field(checkpoint, field, value)
    kept = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    resume = tune_args("--scenario", str(PAPER), "--out", str(out), "--resume", *TINY)
    with pytest.raises(ValueError) as refused:  # the swarm command prints it, status 2
        run_tune(resume)
    said = str(refused.value)
    assert f"{checkpoint} is damaged ({named}" in said, said
    assert "\n" not in said
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == kept


@pytest.mark.parametrize(
    ("duration", "said"),
    [
        ("1e9", "--duration: evaluation duration 1e+09 s is over ten million control periods"),
        ("100000.01", "(at most 100000 s)"),
    ],
)
def test_a_duration_over_the_tick_limit_is_refused_naming_the_flag(
    tmp_path: Path, duration: str, said: str
) -> None:
    # Before, it was accepted (`swarm sim` refuses it) and computed without end.
    with pytest.raises(ValueError, match="over ten million control periods"):
        evaluation_scenario(load_scenario(PAPER), float(duration))
    out = tmp_path / "tune"
    args = tune_args("--scenario", str(PAPER), "--out", str(out), "--budget", "3")
    args.duration = float(duration)
    with pytest.raises(TuneArgumentError) as refused:
        run_tune(args)
    assert said in str(refused.value)
    assert not out.exists()

"""Checkpoint and resume: an interrupted run resumes to the uninterrupted result."""

from pathlib import Path

import numpy as np
import pytest

from services.tuner import checkpoint as checkpoint_module
from services.tuner.baselines import ParticleSwarm
from services.tuner.benchmark_functions import rastrigin
from services.tuner.checkpoint import (
    CheckpointDamagedError,
    CheckpointMismatchError,
    load_checkpoint,
)
from services.tuner.evaluation import ProgressCallback
from services.tuner.generational import run_population_algorithm
from services.tuner.registry import ALGORITHMS

ALGORITHM_NAMES = sorted(ALGORITHMS)


class SimulatedKillError(Exception):
    """Stands in for a killed process."""


def interrupt_at(generation: int) -> ProgressCallback:
    def progress(current: int, n_evaluations: int, best_cost: float) -> None:
        if current == generation:
            raise SimulatedKillError

    return progress


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_resumed_run_equals_uninterrupted_run(name: str, tmp_path: Path) -> None:
    run = ALGORITHMS[name]
    uninterrupted = run(rastrigin, 4, 1010, 17)

    path = tmp_path / f"{name}.npz"
    with pytest.raises(SimulatedKillError):
        run(rastrigin, 4, 1010, 17, path, interrupt_at(8), checkpoint_every=3)
    saved = load_checkpoint(path)
    assert saved.generation == 6
    assert len(saved.history_best_cost) == 7

    evaluated_after_resume: list[int] = []

    def counting_rastrigin(candidates: np.ndarray) -> np.ndarray:
        evaluated_after_resume.append(candidates.shape[0])
        return rastrigin(candidates)

    resumed = run(counting_rastrigin, 4, 1010, 17, path, checkpoint_every=3)
    assert resumed.same_as(uninterrupted)
    assert sum(evaluated_after_resume) == 1010 - saved.n_evaluations
    assert load_checkpoint(path).generation == uninterrupted.n_generations


def test_finished_checkpoint_returns_the_result_without_evaluating(tmp_path: Path) -> None:
    path = tmp_path / "ofa.npz"
    finished = ALGORITHMS["ofa"](rastrigin, 3, 300, 1, path)

    def must_not_run(candidates: np.ndarray) -> np.ndarray:
        raise AssertionError("a finished run must not evaluate again")

    assert ALGORITHMS["ofa"](must_not_run, 3, 300, 1, path).same_as(finished)


def test_checkpoint_of_a_different_run_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "ga.npz"
    ALGORITHMS["ga"](rastrigin, 3, 300, 1, path)
    with pytest.raises(CheckpointMismatchError):
        ALGORITHMS["ga"](rastrigin, 3, 400, 1, path)
    with pytest.raises(CheckpointMismatchError):
        ALGORITHMS["pso"](rastrigin, 3, 300, 1, path)
    with pytest.raises(CheckpointMismatchError):
        ALGORITHMS["ga"](rastrigin, 3, 300, 2, path)


@pytest.mark.parametrize("damage", ["cut short", "overwritten", "emptied", "a field gone"])
def test_a_damaged_checkpoint_is_refused_as_damaged_and_nothing_runs(
    tmp_path: Path, damage: str
) -> None:
    path = tmp_path / "ga.npz"
    ALGORITHMS["ga"](rastrigin, 3, 300, 1, path)
    whole = path.read_bytes()
    if damage == "cut short":
        path.write_bytes(whole[: len(whole) // 2])
    elif damage == "overwritten":
        path.write_bytes(bytes(range(256)) * 20)
    elif damage == "emptied":
        path.write_bytes(b"")
    else:
        with np.load(path, allow_pickle=False) as archive:
            kept = {key: archive[key] for key in archive.files if key != "positions"}
        with path.open("wb") as handle:
            np.savez(handle, **kept)

    def must_not_run(x: np.ndarray) -> np.ndarray:
        raise AssertionError("a damaged checkpoint must not start a run")

    with pytest.raises(CheckpointDamagedError, match=r"ga\.npz is damaged .* move it away"):
        load_checkpoint(path)
    with pytest.raises(CheckpointDamagedError):
        ALGORITHMS["ga"](must_not_run, 3, 300, 1, path)


FIELD_DAMAGE = {
    "positions of another dimension": ("positions", lambda a: a[:, :2], "positions: shape"),
    "positions outside the cube": ("positions", lambda a: a + 5.0, "outside [0, 1]"),
    "NaN costs": ("costs", lambda a: a * np.nan, "costs: shape"),
    "best_x of another dimension": ("best_x", lambda a: a[:1], "best_x: not 3 values"),
    "evaluations over the budget": ("n_evaluations", lambda a: a + 10**9, "n_evaluations: "),
    "negative evaluations": ("n_evaluations", lambda a: a * 0 - 5, "n_evaluations: -5"),
    "short history": ("history_best_cost", lambda a: a[:1], "history: its two columns"),
    "velocities of another population": (
        "auxiliary__velocities",
        lambda a: a[:2],
        "velocities: shape (2, 3)",
    ),
    "a state of another generator": (
        "rng_state",
        lambda a: np.array('{"bit_generator": "PCG64", "state": 5}'),
        "rng_state:",
    ),
}


PCG64_NEGATIVE_STATE = (
    '{"bit_generator": "PCG64", "state": {"state": -1, "inc": 1}, "has_uint32": 0, "uinteger": 0}'
)
VALUE_DAMAGE = {
    "infinite best cost": ("best_cost", lambda a: np.array(np.inf), "best_cost: inf"),
    "minus infinite best cost": ("best_cost", lambda a: np.array(-np.inf), "best_cost: -inf"),
    "zero best cost": ("best_cost", lambda a: np.array(0.0), "best_cost: 0.0"),
    "negative best cost": ("best_cost", lambda a: np.array(-1.0), "best_cost: -1.0"),
    "best cost an array": ("best_cost", lambda a: np.array([1.0, 2.0]), "best_cost: shape (2,)"),
    "zero costs": ("costs", lambda a: a * 0.0, "costs: shape"),
    "generation an array": ("generation", lambda a: np.array([1, 2]), "generation: shape (2,)"),
    "generation complex": ("generation", lambda a: np.array(1 + 2j), "dtype complex128"),
    "generation beyond the history": ("generation", lambda a: a + 3, "generation: 7, but"),
    "zero history costs": ("history_best_cost", lambda a: a * 0.0, "history_best_cost: "),
    "negative history costs": ("history_best_cost", lambda a: -a, "history_best_cost: "),
    "NaN history costs": ("history_best_cost", lambda a: a * np.nan, "history_best_cost: "),
    "negative history counts": ("history_n_evaluations", lambda a: a * 0 - 5, "history_n_e"),
    "a negative PCG64 state": ("rng_state", lambda a: np.array(PCG64_NEGATIVE_STATE), "rng_st"),
    "a state that is a list": ("rng_state", lambda a: np.array("[1, 2]"), "rng_state: not a"),
    "format version an array": ("format_version", lambda a: np.array([1]), "format_version: "),
}

assert not set(FIELD_DAMAGE) & set(VALUE_DAMAGE)


@pytest.mark.parametrize("damage", sorted(FIELD_DAMAGE) + sorted(VALUE_DAMAGE))
def test_a_checkpoint_whose_fields_were_changed_is_refused_naming_the_field(
    tmp_path: Path, damage: str
) -> None:
    # Before, a readable archive was trusted field by field: a traceback deep in the resumed
    # generation, or results written from values no run produces.  For VALUE_DAMAGE: a
    # ValueError from the SNR fitness, a TypeError from int() of an array, an OverflowError
    # from the generator, or, for the history counts, a resume.
    field, change, named = {**FIELD_DAMAGE, **VALUE_DAMAGE}[damage]
    path = tmp_path / "pso.npz"
    with pytest.raises(SimulatedKillError):
        ALGORITHMS["pso"](rastrigin, 3, 600, 1, path, interrupt_at(4), checkpoint_every=2)
    with np.load(path, allow_pickle=False) as archive:
        fields = {key: archive[key] for key in archive.files}
    fields[field] = change(fields[field])
    with path.open("wb") as handle:
        np.savez(handle, **fields)

    def must_not_run(x: np.ndarray) -> np.ndarray:
        raise AssertionError("a damaged checkpoint must not start a run")

    with pytest.raises(CheckpointDamagedError, match=r"pso\.npz is damaged \(") as refused:
        ALGORITHMS["pso"](must_not_run, 3, 600, 1, path)
    assert named in str(refused.value), refused.value
    assert "\n" not in str(refused.value)


def test_failed_save_keeps_the_previous_checkpoint_and_leaves_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "fa.npz"
    with pytest.raises(SimulatedKillError):
        ALGORITHMS["fa"](rastrigin, 3, 2000, 4, path, interrupt_at(2), checkpoint_every=1)
    before = path.read_bytes()

    def failing_savez(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(checkpoint_module.np, "savez", failing_savez)
    with pytest.raises(OSError, match="disk full"):
        ALGORITHMS["fa"](rastrigin, 3, 2000, 4, path, checkpoint_every=1)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fa.npz"]


def test_checkpoint_holds_the_generator_state_of_its_generation(tmp_path: Path) -> None:
    path = tmp_path / "pso.npz"
    rng = np.random.default_rng(8)
    state_at_generation_5: dict[str, object] = {}

    def capture_then_stop(generation: int, n_evaluations: int, best_cost: float) -> None:
        if generation == 5:
            state_at_generation_5.update(rng.bit_generator.state)
            raise SimulatedKillError

    with pytest.raises(SimulatedKillError):
        run_population_algorithm(
            ParticleSwarm(),
            rastrigin,
            3,
            1000,
            rng,
            checkpoint_path=path,
            checkpoint_every=5,
            progress=capture_then_stop,
        )
    saved = load_checkpoint(path)
    assert saved.generation == 5
    assert dict(saved.rng_state) == state_at_generation_5
    assert set(saved.auxiliary) == {"velocities", "personal_best_positions", "personal_best_costs"}

"""One OFA-fuzzy tuning run on disk: optimiser + fitness (eq. 16) + resumable outputs.

:func:`tune_fuzzy_scheduler` searches the decision space of
:mod:`services.tuner.fuzzy_encoding` with one registered optimiser (OFA, FA, GA or PSO,
:data:`~services.tuner.registry.ALGORITHMS`) on the objective of
:mod:`services.tuner.fitness`, and keeps its state in a folder of its own:

``checkpoint.npz``
    the optimiser's complete state after every generation, so an interrupted run resumes
    without losing any finished generation (the evaluations of the generation in flight are
    redone, which gives the same costs: the objective is deterministic);
``run.json``
    the settings that must match for a resume (scenario, evaluation duration, noise seed,
    optimiser seed, budget, collision penalty);
``convergence.csv``
    one row per generation: generation, evaluations, best_cost, best_fitness_db (the Fig. 14
    curve; the best cost never increases);
``best_fuzzy.yaml``
    the best scheduler as a :class:`~robot_firmware.control.fuzzy_parameters.FuzzyParameters`
    file, which a scenario's ``fuzzy_parameter_file`` and the robots load.

:func:`write_convergence_figure` draws Fig. 14: best fitness so far against evaluations for
several algorithms run with the same settings.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from services.tuner.checkpoint import CheckpointDamagedError, checkpoint_problem, load_checkpoint
from services.tuner.evaluation import FloatArray, Objective, ProgressCallback
from services.tuner.fitness import DEFAULT_COLLISION_PENALTY, evaluation_scenario, make_objective
from services.tuner.fuzzy_encoding import DIMENSION, to_parameters
from services.tuner.registry import ALGORITHMS
from services.tuner.result import OptimisationResult
from swarm_config.atomic_files import write_file_atomically
from swarm_config.scenario import Scenario

CHECKPOINT_NAME = "checkpoint.npz"
RUN_SETTINGS_NAME = "run.json"
CONVERGENCE_NAME = "convergence.csv"
BEST_FUZZY_NAME = "best_fuzzy.yaml"
CONVERGENCE_FIELDS = ("generation", "evaluations", "best_cost", "best_fitness_db")


def scenario_digest(scenario: Scenario) -> str:
    """SHA-256 of the scenario's content (its fuzzy parameter file path aside)."""
    text = scenario.model_dump_json(exclude={"fuzzy_parameter_file"})
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class TuningSettings:
    """What defines a tuning run; a resume must match it field by field."""

    algorithm: str
    scenario_name: str
    scenario_sha256: str
    budget: int
    seed: int
    noise_seed: int
    evaluation_duration_s: float
    fitness_window_start_s: float
    collision_penalty: float

    @staticmethod
    def create(
        scenario: Scenario,
        algorithm: str,
        budget: int,
        seed: int,
        duration_s: float | None = None,
        collision_penalty: float = DEFAULT_COLLISION_PENALTY,
    ) -> TuningSettings:
        """Check the arguments (ValueError on a mistake) and fix the run's settings."""
        if algorithm not in ALGORITHMS:
            raise ValueError(
                f"unknown algorithm {algorithm!r}; choose from {', '.join(sorted(ALGORITHMS))}"
            )
        if budget < 1:
            raise ValueError(f"the evaluation budget must be at least 1, got {budget}")
        if seed < 0:
            raise ValueError(f"the seed must be non-negative, got {seed}")
        if collision_penalty < 0.0:
            raise ValueError(f"collision_penalty must be non-negative, got {collision_penalty}")
        evaluated = evaluation_scenario(scenario, duration_s)
        return TuningSettings(
            algorithm=algorithm,
            scenario_name=scenario.name,
            scenario_sha256=scenario_digest(scenario),
            budget=budget,
            seed=seed,
            noise_seed=scenario.seed,
            evaluation_duration_s=evaluated.duration_s,
            fitness_window_start_s=evaluated.metrics.fitness_window_start_s,
            collision_penalty=collision_penalty,
        )

    def comparable_with(self, other: TuningSettings) -> bool:
        """Same problem and budget (the algorithm aside): curves that belong in one figure."""
        mine = asdict(self)
        theirs = asdict(other)
        mine.pop("algorithm")
        theirs.pop("algorithm")
        return mine == theirs


def read_settings(path: Path) -> TuningSettings | None:
    """The settings stored in a run folder's run.json, or None if absent or unreadable."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return TuningSettings(**data)
    except (OSError, ValueError, TypeError, RecursionError):
        return None


def write_text_atomically(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` in one rename (swarm_config/atomic_files.py);
    FileWriteError, the old file untouched, when it cannot be written."""
    write_file_atomically(path, text.encode("utf-8"))


def convergence_rows(result: OptimisationResult) -> list[dict[str, float | int]]:
    """Per-generation rows of the Fig. 14 curve from an optimiser's history."""
    history = result.history
    fitness_db = history.best_fitness_db
    return [
        {
            "generation": generation,
            "evaluations": int(history.n_evaluations[generation]),
            "best_cost": float(history.best_cost[generation]),
            "best_fitness_db": float(fitness_db[generation]),
        }
        for generation in range(history.best_cost.shape[0])
    ]


def write_convergence_csv(
    path: Path, rows: Sequence[Mapping[str, object]], fields: Sequence[str]
) -> None:
    """Write rows as CSV with a header (floats in full precision)."""
    lines: list[str] = [",".join(fields)]
    for row in rows:
        lines.append(
            ",".join(repr(row[f]) if isinstance(row[f], float) else str(row[f]) for f in fields)
        )
    write_text_atomically(path, "\n".join(lines) + "\n")


def read_convergence_csv(path: Path) -> list[dict[str, str]]:
    """Rows of a convergence CSV as strings keyed by column name."""
    with path.open(encoding="utf-8", newline="") as stream:
        return list(csv.DictReader(stream))


def best_fuzzy_text(parameters: FuzzyParameters, header_lines: Sequence[str]) -> str:
    """A fuzzy parameter file with a comment header; `load_fuzzy_parameters` reads it."""
    header = "".join(f"# {line}\n" for line in header_lines)
    return header + parameters.dump_yaml()


@dataclass(frozen=True)
class TuningOutcome:
    """What one algorithm's run produced, and how long this invocation spent on it."""

    settings: TuningSettings
    result: OptimisationResult
    run_dir: Path
    resumed_evaluations: int
    wall_time_s: float

    @property
    def evaluations_per_s(self) -> float:
        """Evaluations done by this invocation per wall-clock second."""
        done = self.result.n_evaluations - self.resumed_evaluations
        return done / self.wall_time_s if self.wall_time_s > 0.0 else math.nan

    @property
    def best_parameters(self) -> FuzzyParameters:
        return to_parameters(self.result.best_x)


ProgressFactory = Callable[[TuningSettings, int], ProgressCallback | None]
"""Given the settings and the evaluations already done (resume), a per-generation callback."""


class ObjectiveFactory(Protocol):
    """Builds the objective of a run, as :func:`~services.tuner.fitness.make_objective` does.

    Another factory may evaluate elsewhere (:meth:`services.tuner.cluster.RayCluster.objective`
    on a Ray cluster) but must give the same costs.
    """

    def __call__(
        self, scenario: Scenario, *, duration_s: float | None, collision_penalty: float
    ) -> Objective: ...


def prepare_run_dir(run_dir: Path, settings: TuningSettings, resume: bool) -> int:
    """Check the folder for a resume or a fresh start; return the evaluations already done.

    A fresh start refuses to overwrite an existing checkpoint; a resume refuses a checkpoint
    written with other settings. Both are ValueErrors with the remedy in the message.
    """
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"{run_dir} exists and is not a folder")
    checkpoint = run_dir / CHECKPOINT_NAME
    if not checkpoint.exists():
        return 0
    if not resume:
        raise ValueError(
            f"{checkpoint} exists from an earlier run; pass --resume to continue it "
            "or choose another output folder"
        )
    stored = read_settings(run_dir / RUN_SETTINGS_NAME)
    if stored is None:
        raise ValueError(f"{run_dir / RUN_SETTINGS_NAME} is missing or unreadable; cannot resume")
    if stored != settings:
        differing = [
            f"{name} ({getattr(stored, name)} then, {getattr(settings, name)} now)"
            for name in asdict(settings)
            if getattr(stored, name) != getattr(settings, name)
        ]
        raise ValueError(
            f"cannot resume {run_dir}: it was started with other settings: {', '.join(differing)}"
        )
    loaded = load_checkpoint(checkpoint)
    problem = checkpoint_problem(loaded, DIMENSION, settings.budget)
    if problem is not None:
        raise CheckpointDamagedError.at(checkpoint, problem)
    return loaded.n_evaluations


def tune_fuzzy_scheduler(
    scenario: Scenario,
    settings: TuningSettings,
    run_dir: Path,
    *,
    resume: bool = False,
    progress: ProgressFactory | None = None,
    checkpoint_every: int = 1,
    objective_factory: ObjectiveFactory | None = None,
) -> TuningOutcome:
    """Run one algorithm on eq. 16 for ``scenario`` and write its folder (see module docstring).

    ``settings`` come from :meth:`TuningSettings.create` with the same scenario. With
    ``resume`` an existing checkpoint in ``run_dir`` is continued; the result is the same as
    that of an uninterrupted run. ``objective_factory`` (default
    :func:`~services.tuner.fitness.make_objective`, in this process) builds the objective.
    """
    if settings.scenario_sha256 != scenario_digest(scenario):
        raise ValueError("settings were made for another scenario")
    resumed = prepare_run_dir(run_dir, settings, resume)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomically(
        run_dir / RUN_SETTINGS_NAME, json.dumps(asdict(settings), indent=2) + "\n"
    )
    objective = (objective_factory or make_objective)(
        scenario,
        duration_s=settings.evaluation_duration_s,
        collision_penalty=settings.collision_penalty,
    )
    callback = progress(settings, resumed) if progress is not None else None
    start = time.perf_counter()
    result = ALGORITHMS[settings.algorithm](
        objective,
        DIMENSION,
        settings.budget,
        settings.seed,
        run_dir / CHECKPOINT_NAME,
        callback,
        checkpoint_every=checkpoint_every,
    )
    wall_time_s = time.perf_counter() - start
    write_convergence_csv(run_dir / CONVERGENCE_NAME, convergence_rows(result), CONVERGENCE_FIELDS)
    outcome = TuningOutcome(settings, result, run_dir, resumed, wall_time_s)
    write_text_atomically(
        run_dir / BEST_FUZZY_NAME,
        best_fuzzy_text(
            outcome.best_parameters,
            [
                f"fuzzy scheduler tuned by {settings.algorithm} on scenario "
                f"{settings.scenario_name} (eq. 16 fitness {result.best_fitness_db:.3f} dB,",
                f"{result.n_evaluations} evaluations of {settings.evaluation_duration_s:g} s, "
                f"optimiser seed {settings.seed}, noise seed {settings.noise_seed})",
            ],
        ),
    )
    return outcome


@dataclass(frozen=True)
class ConvergenceCurve:
    """Best fitness so far against evaluations, for one algorithm (Fig. 14)."""

    algorithm: str
    evaluations: FloatArray
    best_fitness_db: FloatArray


def curve_from_result(algorithm: str, result: OptimisationResult) -> ConvergenceCurve:
    return ConvergenceCurve(
        algorithm,
        result.history.n_evaluations.astype(np.float64),
        result.history.best_fitness_db,
    )


def comparable_curves(out_dir: Path, settings: TuningSettings) -> list[ConvergenceCurve]:
    """Curves of every run folder in ``out_dir`` whose settings are comparable with ``settings``.

    Lets ``swarm tune --algo ga`` into a folder where ``--algo ofa`` ran before draw both.
    """
    curves: list[ConvergenceCurve] = []
    if not out_dir.is_dir():
        return curves
    for run_dir in sorted(p for p in out_dir.iterdir() if p.is_dir()):
        stored = read_settings(run_dir / RUN_SETTINGS_NAME)
        csv_path = run_dir / CONVERGENCE_NAME
        if stored is None or not stored.comparable_with(settings) or not csv_path.exists():
            continue
        rows = read_convergence_csv(csv_path)
        if not rows:
            continue
        curves.append(
            ConvergenceCurve(
                stored.algorithm,
                np.array([float(r["evaluations"]) for r in rows]),
                np.array([float(r["best_fitness_db"]) for r in rows]),
            )
        )
    return curves


ALGORITHM_LABELS = {
    "ofa": "OFA-fuzzy",
    "fa": "FA-fuzzy",
    "ga": "GA-fuzzy",
    "pso": "PSO-fuzzy",
    "random": "random search",
}
ALGORITHM_COLOURS = {
    "ofa": "#d62728",
    "fa": "#ff7f0e",
    "ga": "#1f77b4",
    "pso": "#2ca02c",
    "random": "#9467bd",
}


def write_convergence_figure(
    path: Path,
    curves: Sequence[ConvergenceCurve],
    title: str,
    reference_db: float | None = None,
) -> Path:
    """Fig. 14: best eq. 16 fitness so far against evaluations, one step curve per algorithm.

    ``reference_db``, if given, is drawn as a dashed line (Table 2 with even centres).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from services.sim.figures import save_figure

    figure, axes = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for curve in curves:
        axes.step(
            curve.evaluations,
            curve.best_fitness_db,
            where="post",
            label=ALGORITHM_LABELS.get(curve.algorithm, curve.algorithm),
            color=ALGORITHM_COLOURS.get(curve.algorithm),
            linewidth=1.6,
        )
    if reference_db is not None and math.isfinite(reference_db):
        axes.axhline(
            reference_db, color="0.4", linestyle="--", linewidth=1.0, label="Table 2, even centres"
        )
    axes.set_xlabel("fitness evaluations")
    axes.set_ylabel("best fitness, eq. 16 (dB)")
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    axes.legend(loc="lower right")
    figure.tight_layout()
    return save_figure(figure, path)

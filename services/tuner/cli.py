"""`swarm tune`: tune the fuzzy scheduler (eqs. 6-7, Table 2) on eq. 16 with OFA, FA, GA or PSO.

    swarm tune --scenario FILE --out DIR [--algo ofa|fa|ga|pso|random[,...]] [--budget N]
               [--seed S] [--duration S] [--resume] [--ray HOST:PORT]

``random`` is pure random search at the same budget, the baseline the optimisers must beat.

Each algorithm of ``--algo`` (a comma list runs several, one after the other, at the same budget
and seed) searches the 16-dimensional decision space of :mod:`services.tuner.fuzzy_encoding`;
a candidate is scored by simulating the scenario for ``--duration`` seconds with the scenario's
noise seed, shared by all candidates (:mod:`services.tuner.fitness`). ``--seed`` seeds the
optimiser only. Output folder::

    DIR/best_fuzzy.yaml     best scheduler of this invocation, a fuzzy parameter file
    DIR/convergence.csv     algorithm, generation, evaluations, best_cost, best_fitness_db
    DIR/convergence.png     Fig. 14: best fitness against evaluations, one curve per algorithm
    DIR/tune.json           settings, per-algorithm results, wall time, evaluations per second
    DIR/<algo>/             per algorithm: checkpoint.npz, run.json, convergence.csv,
                            best_fuzzy.yaml

The CSV and the figure gather every algorithm folder in DIR run with the same scenario,
duration, seeds and budget, so ``--algo ofa`` and a later ``--algo ga,pso`` into the same DIR
end up in one figure. The optimiser's state is saved after every generation; ``--resume``
continues an interrupted run (Ctrl-C included) and gives the result an uninterrupted run would.

``--ray HOST:PORT`` evaluates each generation's batch on a Ray cluster
(:mod:`services.tuner.cluster`, ``pip install .[cluster]``), with the same results as a local
run; the optimiser and its checkpoints stay in this process. Without it Ray is never imported.
A cluster that loses its tasks beyond retrying ends the run with status 1, checkpointed.

A user mistake (unreadable scenario, unknown algorithm, bad number, an existing run without
``--resume``) raises :class:`~swarm_config.scenario.ScenarioError` or :class:`TuneArgumentError`, a
ValueError that is also a ScenarioError; the ``swarm`` command prints its message and exits
with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import TextIO

import numpy as np

from services.launcher.run_lock import (
    TUNE_LOCK_FILE_NAME,
    RunDirectoryBusyError,
    RunDirectoryLock,
)
from services.output_folder import OutputFolderError, prepare_output_folder
from services.sim.run import fault_campaign_warning
from services.stop_signals import EXIT_INTERRUPTED
from services.tuner.checkpoint import CheckpointDamagedError
from services.tuner.cluster import ClusterError, RayCluster, connect_cluster
from services.tuner.evaluation import ProgressCallback, snr_fitness_from_cost
from services.tuner.fitness import evaluate_fitness, evaluation_duration_problem
from services.tuner.fuzzy_encoding import encode_default
from services.tuner.fuzzy_tuning import (
    BEST_FUZZY_NAME,
    CONVERGENCE_FIELDS,
    CONVERGENCE_NAME,
    TuningOutcome,
    TuningSettings,
    best_fuzzy_text,
    comparable_curves,
    prepare_run_dir,
    read_convergence_csv,
    tune_fuzzy_scheduler,
    write_convergence_csv,
    write_convergence_figure,
    write_text_atomically,
)
from services.tuner.registry import ALGORITHMS
from swarm_config.atomic_files import FileWriteError
from swarm_config.scenario import Scenario, ScenarioError, load_scenario

DEFAULT_ALGORITHM = "ofa"
DEFAULT_BUDGET = 800
"""Evaluations per algorithm: 20 generations of 40 candidates."""
DEFAULT_EVALUATION_DURATION_S = 30.0
"""Simulated seconds per evaluation (at most the scenario's duration); on the paper scenario eq. 16
then averages over 0-30 s: the approach from the starting poses, more than one lap of the circle
and one pass of the obstacle."""
EXIT_CLUSTER_LOST = 1
EXIT_WRITE_FAILED = 1
EXIT_DAMAGED_CHECKPOINT = 2
"""As for any other refused argument: the folder given to --resume holds no usable run."""


class TuneArgumentError(ScenarioError, ValueError):
    """A mistake on the ``swarm tune`` command line, reported in one line with exit status 2."""


def parse_algorithms(text: str) -> list[str]:
    """``ofa,ga,pso`` to a list of registered names; ValueError names the unknown ones."""
    names = [name.strip().lower() for name in text.split(",") if name.strip()]
    if not names:
        raise ValueError(f"--algo needs one or more of {', '.join(sorted(ALGORITHMS))}")
    unknown = [name for name in names if name not in ALGORITHMS]
    if unknown:
        raise ValueError(
            f"unknown algorithm {', '.join(repr(n) for n in unknown)} in --algo; "
            f"choose from {', '.join(sorted(ALGORITHMS))} (comma separated)"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"--algo lists an algorithm twice: {text}")
    return names


class ProgressLine:
    """One status line on a stream, rewritten in place on a terminal, one line per update else.

    Shows generation, evaluations, best fitness so far (eq. 16, dB) and evaluations per second
    since this invocation started the algorithm.
    """

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.in_place = stream.isatty()
        self.width = 0

    def callback(self, settings: TuningSettings, resumed_evaluations: int) -> ProgressCallback:
        start = time.perf_counter()

        def report(generation: int, n_evaluations: int, best_cost: float) -> None:
            elapsed_s = time.perf_counter() - start
            rate = (n_evaluations - resumed_evaluations) / elapsed_s if elapsed_s > 0 else 0.0
            best_db = float(snr_fitness_from_cost(best_cost))
            self.show(
                f"tune {settings.algorithm:<3} gen {generation:>3}  evals "
                f"{n_evaluations:>{len(str(settings.budget))}}/{settings.budget}  "
                f"best {best_db:7.3f} dB  {rate:5.1f} evals/s  {elapsed_s:6.0f} s"
            )

        return report

    def show(self, text: str) -> None:
        if self.in_place:
            padding = " " * max(0, self.width - len(text))
            self.stream.write("\r" + text + padding)
            self.width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.in_place and self.width:
            self.stream.write("\n")
            self.stream.flush()
        self.width = 0


def add_tune_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``tune`` (handler :func:`run_tune`) on the ``swarm`` command's subparsers."""
    tune = subparsers.add_parser(
        "tune",
        help="tune the fuzzy scheduler on eq. 16 with OFA, FA, GA or PSO",
        description=(
            "Search the fuzzy scheduler's set counts and membership centres (16 numbers) that "
            "maximise the fitness of eq. 16 on a scenario, with the orthogonal firefly "
            "algorithm or a baseline. Writes DIR/best_fuzzy.yaml (load it with a scenario's "
            "fuzzy_parameter_file), DIR/convergence.csv and DIR/convergence.png (Fig. 14); "
            "checkpoints every generation so that --resume continues an interrupted run."
        ),
    )
    tune.add_argument("--scenario", required=True, metavar="FILE", help="scenario YAML file")
    tune.add_argument("--out", required=True, metavar="DIR", help="output folder")
    tune.add_argument(
        "--algo",
        default=DEFAULT_ALGORITHM,
        metavar="NAMES",
        help="ofa, fa, ga, pso or random (random search), or a comma list run one after the "
        f"other at the same budget and seed (default: {DEFAULT_ALGORITHM})",
    )
    tune.add_argument(
        "--budget",
        type=int,
        default=DEFAULT_BUDGET,
        metavar="N",
        help=f"fitness evaluations per algorithm (default: {DEFAULT_BUDGET})",
    )
    tune.add_argument(
        "--seed", type=int, default=0, metavar="S", help="optimiser seed (default: 0)"
    )
    tune.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="simulated seconds per evaluation, from two control periods to ten million (as "
        "`swarm sim --duration`); the fitness window keeps its share of the scenario's run "
        f"(default: {DEFAULT_EVALUATION_DURATION_S:g}, or the scenario's duration if shorter)",
    )
    tune.add_argument("--resume", action="store_true", help="continue the runs checkpointed in DIR")
    tune.add_argument(
        "--ray",
        default=None,
        metavar="HOST:PORT",
        help="evaluate the fitness batches on the Ray cluster whose head is at HOST:PORT "
        "(needs `pip install .[cluster]`; same results as a local run)",
    )
    tune.set_defaults(handler=run_tune)


def _centres_text(values: list[float]) -> str:
    return "[" + ", ".join(f"{v:+.3f}" for v in values) + "]"


def _cm(value_m: float) -> str:
    return "n/a" if not math.isfinite(value_m) else f"{100.0 * value_m:.2f} cm"


def run_tune(args: argparse.Namespace) -> int:
    """Handler of ``swarm tune``; returns the exit status (0, or 130 when interrupted)."""
    wall_start = time.perf_counter()
    cpu_start = time.process_time()
    scenario_path = Path(args.scenario)
    out_dir = Path(args.out)
    try:
        algorithms = parse_algorithms(str(args.algo))
        scenario = load_scenario(scenario_path)
        if args.duration is None:
            duration_s = min(DEFAULT_EVALUATION_DURATION_S, scenario.duration_s)
        else:
            duration_s = float(args.duration)
            problem = evaluation_duration_problem(scenario, duration_s)
            if problem is not None:
                raise ValueError(f"--duration: {problem}")
        all_settings = [
            TuningSettings.create(scenario, name, int(args.budget), int(args.seed), duration_s)
            for name in algorithms
        ]
        for settings in all_settings:  # refuse a clash before any algorithm starts
            prepare_run_dir(out_dir / settings.algorithm, settings, bool(args.resume))
        cluster = None if args.ray is None else connect_cluster(str(args.ray))
        try:
            prepare_output_folder(out_dir, "--out")  # last: a refused run leaves no empty folder
            # One tuner writes a folder's checkpoints and results: held until it returns (each
            # algorithm checks its run folder again under it).
            lock = RunDirectoryLock.acquire(
                out_dir, "output folder", "--out DIR", "swarm tune", TUNE_LOCK_FILE_NAME
            )
        except (OutputFolderError, RunDirectoryBusyError):
            if cluster is not None:
                cluster.close()
            raise
    except ScenarioError:
        raise
    except ValueError as exc:
        raise TuneArgumentError(str(exc)) from None
    warning = fault_campaign_warning(scenario)  # its evaluations are batch simulations
    if warning is not None:
        print(f"swarm tune: {warning}", file=sys.stderr, flush=True)
    try:
        return _tune_and_report(
            args,
            scenario,
            scenario_path,
            out_dir,
            algorithms,
            all_settings,
            cluster,
            wall_start,
            cpu_start,
        )
    finally:
        lock.release()
        if cluster is not None:
            cluster.close()


def _tune_and_report(
    args: argparse.Namespace,
    scenario: Scenario,
    scenario_path: Path,
    out_dir: Path,
    algorithms: list[str],
    all_settings: list[TuningSettings],
    cluster: RayCluster | None,
    wall_start: float,
    cpu_start: float,
) -> int:
    first = all_settings[0]
    print(
        f"tune {','.join(algorithms)} on {scenario.name}: {first.budget} evaluations each of "
        f"{first.evaluation_duration_s:g} s simulated (eq. 16 over t >= "
        f"{first.fitness_window_start_s:g} s), optimiser seed {first.seed}, noise seed "
        f"{first.noise_seed}",
        flush=True,
    )
    if cluster is not None:
        print(f"fitness batches go to the {cluster.describe()}", flush=True)

    progress = ProgressLine(sys.stderr)
    outcomes: list[TuningOutcome] = []
    for settings in all_settings:
        run_dir = out_dir / settings.algorithm
        try:
            outcome = tune_fuzzy_scheduler(
                scenario,
                settings,
                run_dir,
                resume=bool(args.resume),
                progress=progress.callback,
                objective_factory=None if cluster is None else cluster.objective,
            )
        except ClusterError as exc:
            progress.close()
            print(
                f"swarm tune: {exc}; {settings.algorithm} is checkpointed in {run_dir}; run the "
                "same command with --resume to continue",
                file=sys.stderr,
            )
            return EXIT_CLUSTER_LOST
        except CheckpointDamagedError as exc:  # what only resuming it finds (its rng state)
            progress.close()
            print(f"swarm tune: {exc}", file=sys.stderr)
            return EXIT_DAMAGED_CHECKPOINT
        except FileWriteError as exc:
            progress.close()
            print(
                f"swarm tune: {exc}; {settings.algorithm} is checkpointed in {run_dir} up to its "
                "last written generation; make room, then run the same command with --resume",
                file=sys.stderr,
            )
            return EXIT_WRITE_FAILED
        except KeyboardInterrupt:
            progress.close()
            print(
                f"interrupted: {settings.algorithm} is checkpointed in {run_dir}; "
                "run the same command with --resume to continue",
                file=sys.stderr,
            )
            return EXIT_INTERRUPTED
        progress.close()
        outcomes.append(outcome)

    candidates = np.vstack([encode_default()] + [o.result.best_x for o in outcomes])
    check = evaluate_fitness(candidates, scenario, duration_s=first.evaluation_duration_s)
    reference_db = float(check.fitness_db[0])
    best_index = int(np.argmin([o.result.best_cost for o in outcomes]))
    best = outcomes[best_index]

    print(f"  {'Table 2, even centres':<22} fitness (16) {reference_db:8.3f} dB")
    per_algorithm: dict[str, object] = {}
    for k, outcome in enumerate(outcomes, start=1):
        parameters = outcome.best_parameters
        followers = ", ".join(
            f"{name} {_cm(float(value))}"
            for name, value in zip(check.follower_names, check.formation_rms_m[k], strict=True)
        )
        print(
            f"  {outcome.settings.algorithm + ' best':<22} fitness (16) "
            f"{outcome.result.best_fitness_db:8.3f} dB  K = {len(parameters.error_centres)} x "
            f"{len(parameters.rate_centres)}  leader {_cm(float(check.leader_tracking_rms_m[k]))}"
            f", formation {followers}, collisions {int(check.collisions[k])}  "
            f"({outcome.wall_time_s:.0f} s, {outcome.evaluations_per_s:.1f} evals/s)"
        )
        print(
            f"  {'':<22} error centres {_centres_text(parameters.error_centres)}  "
            f"rate centres {_centres_text(parameters.rate_centres)}"
        )
        per_algorithm[outcome.settings.algorithm] = {
            "best_fitness_db": outcome.result.best_fitness_db,
            "best_cost": outcome.result.best_cost,
            "recomputed_best_cost": float(check.cost[k]),
            "n_evaluations": outcome.result.n_evaluations,
            "n_generations": outcome.result.n_generations,
            "wall_time_s": outcome.wall_time_s,
            "evaluations_per_s": outcome.evaluations_per_s,
            "best_x": [float(v) for v in outcome.result.best_x],
            "best_fuzzy": parameters.model_dump(exclude_none=True),
            "leader_tracking_rms_m": float(check.leader_tracking_rms_m[k]),
            "formation_rms_m": dict(
                zip(check.follower_names, map(float, check.formation_rms_m[k]), strict=True)
            ),
            "collisions": int(check.collisions[k]),
        }
        if float(check.cost[k]) != outcome.result.best_cost:
            print(
                f"  warning: {outcome.settings.algorithm}'s best re-evaluates to cost "
                f"{float(check.cost[k])!r}, not {outcome.result.best_cost!r}",
                file=sys.stderr,
            )

    best_path = out_dir / BEST_FUZZY_NAME
    write_text_atomically(
        best_path,
        best_fuzzy_text(
            best.best_parameters,
            [
                f"best of {','.join(algorithms)} on scenario {scenario.name}: eq. 16 fitness "
                f"{best.result.best_fitness_db:.3f} dB ({best.settings.algorithm})",
                f"use it with `fuzzy_parameter_file: {BEST_FUZZY_NAME}` in a scenario",
            ],
        ),
    )

    curves = comparable_curves(out_dir, first)
    rows: list[dict[str, float | int | str]] = []
    for curve in curves:
        for row in read_convergence_csv(out_dir / curve.algorithm / CONVERGENCE_NAME):
            rows.append(
                {
                    "algorithm": curve.algorithm,
                    "generation": int(row["generation"]),
                    "evaluations": int(row["evaluations"]),
                    "best_cost": float(row["best_cost"]),
                    "best_fitness_db": float(row["best_fitness_db"]),
                }
            )
    csv_path = out_dir / CONVERGENCE_NAME
    write_convergence_csv(csv_path, rows, ("algorithm", *CONVERGENCE_FIELDS))
    figure_path = write_convergence_figure(
        out_dir / "convergence.png",
        curves,
        f"{scenario.name}: {first.budget} evaluations of {first.evaluation_duration_s:g} s, "
        f"seed {first.seed}",
        reference_db,
    )
    wall_time_s = time.perf_counter() - wall_start
    summary_path = out_dir / "tune.json"
    summary = {
        "scenario": str(scenario_path),
        "settings": {k: v for k, v in asdict(first).items() if k != "algorithm"},
        "algorithms": algorithms,
        "table2_fitness_db": reference_db,
        "best_algorithm": best.settings.algorithm,
        "results": per_algorithm,
        "wall_time_s": wall_time_s,
        "cpu_time_s": time.process_time() - cpu_start,
    }
    write_text_atomically(summary_path, json.dumps(summary, indent=2) + "\n")
    for path in (best_path, csv_path, figure_path, summary_path):
        print(f"wrote {path}")
    print(f"wall time {wall_time_s:.1f} s (CPU {time.process_time() - cpu_start:.1f} s)")
    return 0

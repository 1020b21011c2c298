"""OFA against FA, GA, PSO and random search on the eq. 16 fitness of a scenario (Fig. 14).

Not a test.

Every algorithm runs once per optimiser seed at the same evaluation budget on the same
objective (:func:`services.tuner.fitness.make_objective`: the scenario simulated for
``--duration`` seconds with its own noise seed, common to all candidates; eq. 16's error term
averaged over the scenario's fitness window, by default the whole run). Random search (uniform
draws in batches of 40) is the floor an optimiser has to clear. Printed, with the machine and
the date:

* per algorithm, the median and interquartile range of the best fitness (dB) over the seeds,
  the best and worst seed, and fitness evaluations per wall-clock second;
* the median best fitness after the initial population and at a quarter, half, three
  quarters and all of the budget (the shape of the Fig. 14 curves);
* OFA against each other algorithm, paired by seed: the median paired difference, wins/ties/
  losses, and the two-sided Wilcoxon signed-rank test (scipy.stats.wilcoxon). With n seeds the
  smallest two-sided p-value the exact test can give is 2 / 2^n (0.0625 for 5 seeds).

Results (every run's best fitness, best vector and convergence history) go to a JSON file,
the median curves to a PNG. Runs are spread over ``--jobs`` processes. Every finished run is
appended at once to ``<json>.runs.jsonl``; started again with the same settings, the script
takes the runs found there and runs only the rest, so a killed benchmark loses at most the
runs in progress (``--fresh`` ignores them; ``--finished-only`` runs nothing and reports the
seeds already finished by every algorithm). The defaults (5 algorithms, 10 seeds, 600
evaluations of 30 s, all cores) take about 30 minutes on an idle 2-core machine.

``--ray HOST:PORT`` runs them on a Ray cluster instead, one whole optimiser run per task
(:meth:`services.tuner.cluster.RayCluster.map`; a run lost with its node is run again), and then
runs the same runs locally with ``--jobs`` processes: it prints both wall times, measured in
this invocation, and whether every run gave the same result both ways (``--ray-only`` skips
the local pass). Runs finished on the cluster go to ``<json>.runs.jsonl`` as above.

    .venv/bin/python bench/tuner_comparison.py [--seeds 10] [--budget 600] [--duration 30]
        [--algos ofa,fa,ga,pso,random] [--jobs N] [--json runs/bench/tuner_comparison.json]
        [--ray HOST:PORT [--ray-only]]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from arguments import positive_float, positive_int
from machine import machine_lines, machine_record
from scipy.stats import wilcoxon

from services.tuner.cluster import ClusterError, RayCluster, connect_cluster
from services.tuner.fitness import evaluate_fitness, make_objective
from services.tuner.fuzzy_encoding import DIMENSION, encode_default, to_parameters
from services.tuner.fuzzy_tuning import (
    ConvergenceCurve,
    write_convergence_figure,
)
from services.tuner.registry import ALGORITHMS
from swarm_config.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class RunRecord:
    """One optimiser run: what the tables and the JSON file need, as plain values."""

    algorithm: str
    seed: int
    best_fitness_db: float
    best_cost: float
    n_evaluations: int
    wall_time_s: float
    evaluations_per_s: float
    best_x: list[float]
    rule_count: int
    history_evaluations: list[int]
    history_best_fitness_db: list[float]

    def result_fields(self) -> dict[str, object]:
        """Everything but the timings: what a run on the cluster and a local one share."""
        fields = asdict(self)
        del fields["wall_time_s"], fields["evaluations_per_s"]
        return fields


def run_one(
    scenario: Scenario, algorithm: str, seed: int, budget: int, duration_s: float
) -> RunRecord:
    objective = make_objective(scenario, duration_s=duration_s)
    start = time.perf_counter()
    result = ALGORITHMS[algorithm](objective, DIMENSION, budget, seed)
    wall_s = time.perf_counter() - start
    parameters = to_parameters(result.best_x)
    return RunRecord(
        algorithm=algorithm,
        seed=seed,
        best_fitness_db=result.best_fitness_db,
        best_cost=result.best_cost,
        n_evaluations=result.n_evaluations,
        wall_time_s=wall_s,
        evaluations_per_s=result.n_evaluations / wall_s,
        best_x=result.best_x.tolist(),
        rule_count=len(parameters.error_centres) * len(parameters.rate_centres),
        history_evaluations=result.history.n_evaluations.tolist(),
        history_best_fitness_db=result.history.best_fitness_db.tolist(),
    )


def run_settings(args: argparse.Namespace) -> dict[str, object]:
    """What makes two runs of one algorithm and seed the same run."""
    return {
        "scenario": str(args.scenario.resolve()),
        "budget": args.budget,
        "duration_s": args.duration,
        "fitness_window_start_s": load_scenario(args.scenario).metrics.fitness_window_start_s,
    }


def load_finished_runs(
    checkpoint_path: Path, settings: dict[str, object]
) -> dict[tuple[str, int], RunRecord]:
    """Runs already finished with these settings; lines from other settings or cut short by
    a kill are skipped."""
    finished: dict[tuple[str, int], RunRecord] = {}
    if not checkpoint_path.exists():
        return finished
    for line in checkpoint_path.read_text(encoding="utf-8").splitlines():
        try:
            entry = json.loads(line)
            if entry.get("settings") != settings:
                continue
            run = RunRecord(**entry["run"])
        except (ValueError, TypeError, KeyError):
            continue
        finished[(run.algorithm, run.seed)] = run
    return finished


def append_finished_run(checkpoint_path: Path, settings: dict[str, object], run: RunRecord) -> None:
    with checkpoint_path.open("a", encoding="utf-8") as stream:
        stream.write(json.dumps({"settings": settings, "run": asdict(run)}) + "\n")
        stream.flush()
        os.fsync(stream.fileno())


Task = tuple[str, int]
"""(algorithm, optimiser seed): one run."""


def run_locally(
    scenario: Scenario,
    pending: list[Task],
    args: argparse.Namespace,
    on_finished: Callable[[RunRecord], None],
    *,
    own_sessions: bool = False,
) -> dict[Task, RunRecord]:
    """The runs on ``args.jobs`` local processes; ``on_finished`` sees each as it ends.

    ``own_sessions`` puts each process in a session of its own, as the processes of each Ray
    node are in theirs: with the kernel's autogroup scheduling a busy shared machine shares its
    CPUs between sessions, so the comparison with a cluster on the same machine is then fair.
    """
    runs: dict[Task, RunRecord] = {}
    initializer = os.setsid if own_sessions else None
    with ProcessPoolExecutor(max_workers=args.jobs, initializer=initializer) as pool:
        futures = {
            pool.submit(run_one, scenario, a, s, args.budget, args.duration): (a, s)
            for a, s in pending
        }
        for future in as_completed(futures):
            run = future.result()
            runs[futures[future]] = run
            on_finished(run)
    return runs


def run_on_cluster(
    cluster: RayCluster,
    scenario: Scenario,
    pending: list[Task],
    args: argparse.Namespace,
    on_finished: Callable[[RunRecord], None],
) -> dict[Task, RunRecord]:
    """The runs as Ray tasks, one whole run each; ``on_finished`` sees each as it ends."""
    results = cluster.map(
        run_one,
        [(scenario, a, s, args.budget, args.duration) for a, s in pending],
        on_result=lambda index, run: on_finished(run),
    )
    return dict(zip(pending, results, strict=True))


def best_at(run: RunRecord, evaluations: int) -> float:
    """Best fitness a run had reached after ``evaluations`` evaluations (NaN before any)."""
    spent = np.asarray(run.history_evaluations)
    reached = np.nonzero(spent <= evaluations)[0]
    return float(run.history_best_fitness_db[reached[-1]]) if reached.size else float("nan")


def quartiles(values: list[float]) -> tuple[float, float, float]:
    q25, q50, q75 = np.percentile(values, [25, 50, 75])
    return float(q25), float(q50), float(q75)


def paired_test(ofa: list[float], other: list[float]) -> dict[str, object]:
    difference = np.asarray(ofa) - np.asarray(other)
    wins = int(np.sum(difference > 0))
    ties = int(np.sum(difference == 0))
    losses = int(np.sum(difference < 0))
    record: dict[str, object] = {
        "median_difference_db": float(np.median(difference)),
        "wins": wins,
        "ties": ties,
        "losses": losses,
    }
    if wins + losses == 0:
        record.update(statistic=None, p_value=None)
        return record
    test = wilcoxon(ofa, other, zero_method="wilcox", alternative="two-sided")
    record.update(statistic=float(test.statistic), p_value=float(test.pvalue))
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=Path, default=ROOT / "configs/scenarios/paper.yaml")
    parser.add_argument("--algos", default="ofa,fa,ga,pso,random")
    parser.add_argument("--seeds", type=positive_int, default=10, help="optimiser seeds 0..N-1")
    parser.add_argument("--budget", type=positive_int, default=600, help="evaluations per run")
    parser.add_argument(
        "--duration", type=positive_float, default=30.0, help="simulated s per evaluation"
    )
    parser.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1)
    parser.add_argument(
        "--json", type=Path, default=ROOT / "runs/bench/tuner_comparison.json", dest="json_path"
    )
    parser.add_argument("--figure", type=Path, default=None, help="PNG (default: beside JSON)")
    parser.add_argument(
        "--ray",
        default=None,
        metavar="HOST:PORT",
        help="run on the Ray cluster whose head is at HOST:PORT, then the same runs locally "
        "for the wall-time comparison",
    )
    parser.add_argument(
        "--ray-only", action="store_true", help="with --ray: skip the local comparison pass"
    )
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="ignore runs finished earlier (<json>.runs.jsonl) and run every one again",
    )
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="run nothing: report the seeds whose runs of every algorithm are already in "
        "<json>.runs.jsonl (a partial table while a long comparison is still running)",
    )
    args = parser.parse_args()
    if args.ray_only and args.ray is None:
        parser.error("--ray-only needs --ray HOST:PORT")
    algorithms = [a.strip() for a in args.algos.split(",") if a.strip()]
    unknown = [a for a in algorithms if a not in ALGORITHMS]
    if unknown or not algorithms:
        parser.error(f"unknown algorithm(s) {unknown}; choose from {sorted(ALGORITHMS)}")
    if args.seeds < 1 or args.budget < 1 or args.jobs < 1:
        parser.error("--seeds, --budget and --jobs must be at least 1")

    scenario = load_scenario(args.scenario)
    reference = evaluate_fitness(encode_default(), scenario, duration_s=args.duration)
    seeds = list(range(args.seeds))
    tasks = [(a, s) for s in seeds for a in algorithms]
    args.json_path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint_path = args.json_path.with_name(args.json_path.name + ".runs.jsonl")
    settings = run_settings(args)
    if args.fresh:
        checkpoint_path.unlink(missing_ok=True)
    finished = load_finished_runs(checkpoint_path, settings)
    if args.finished_only:
        seeds = [s for s in seeds if all((a, s) in finished for a in algorithms)]
        if not seeds:
            parser.error(f"no seed has finished runs of every algorithm in {checkpoint_path}")
        tasks = [(a, s) for s in seeds for a in algorithms]
    pending = [task for task in tasks if task not in finished]
    if len(pending) < len(tasks):
        print(f"# {len(tasks) - len(pending)} runs taken from {checkpoint_path}", flush=True)
    cluster = None
    if args.ray is not None:
        try:
            cluster = connect_cluster(args.ray)
        except ClusterError as exc:
            parser.error(str(exc))

    def record(run: RunRecord) -> None:
        append_finished_run(checkpoint_path, settings, run)
        finished[(run.algorithm, run.seed)] = run
        print(
            f"# {len(finished)}/{len(tasks)} {run.algorithm} seed {run.seed}: "
            f"{run.best_fitness_db:.3f} dB, {run.wall_time_s:.0f} s",
            flush=True,
        )

    local_wall_s: float | None = None
    differing: list[Task] = []
    wall_start = time.perf_counter()
    if cluster is None:
        run_locally(scenario, pending, args, record)
        total_wall_s = time.perf_counter() - wall_start
        where = f"{args.jobs} processes"
    else:
        with cluster:
            where = cluster.describe()
            print(f"# {len(pending)} runs on the {where}", flush=True)
            cluster_runs = run_on_cluster(cluster, scenario, pending, args, record)
            total_wall_s = time.perf_counter() - wall_start
        if not args.ray_only and pending:
            print(f"# the same {len(pending)} runs locally, {args.jobs} processes", flush=True)
            local_start = time.perf_counter()
            local_runs = run_locally(scenario, pending, args, lambda run: None, own_sessions=True)
            local_wall_s = time.perf_counter() - local_start
            differing = [
                task
                for task in pending
                if local_runs[task].result_fields() != cluster_runs[task].result_fields()
            ]
    runs = [finished[task] for task in tasks]

    by_algorithm = {
        a: sorted((r for r in runs if r.algorithm == a), key=lambda r: r.seed) for a in algorithms
    }
    best = {a: [r.best_fitness_db for r in rs] for a, rs in by_algorithm.items()}

    for line in machine_lines():
        print(line)
    print(
        f"# scenario {scenario.name}: eq. 16 over t >= {reference.fitness_window_start_s:g} s of "
        f"{reference.duration_s:g} s simulated, noise seed {reference.seed} (common to all)"
    )
    print(
        f"# {len(algorithms)} algorithms x {len(seeds)} optimiser seeds x {args.budget} "
        f"evaluations, {where}, {total_wall_s:.0f} s wall"
        f" for the {len(pending)} runs not taken from the checkpoint"
    )
    if local_wall_s is not None:
        print(
            f"# wall time of the {len(pending)} runs: Ray {total_wall_s:.1f} s, local "
            f"({args.jobs} processes) {local_wall_s:.1f} s, ratio local/Ray "
            f"{local_wall_s / total_wall_s:.2f}; "
            + (
                "every run gave the same result both ways"
                if not differing
                else f"{len(differing)} runs DIFFER: {differing}"
            )
        )
    print(f"# Table 2 with even centres: {float(reference.fitness_db[0]):.3f} dB")
    print()
    print("best fitness (16) over seeds, dB")
    print(
        f"{'algorithm':<10}{'median':>9}{'IQR':>17}{'min':>9}{'max':>9}"
        f"{'evals/s':>10}{'K (median)':>12}"
    )
    for a in algorithms:
        q25, q50, q75 = quartiles(best[a])
        rate = statistics.median(r.evaluations_per_s for r in by_algorithm[a])
        rules = statistics.median(r.rule_count for r in by_algorithm[a])
        print(
            f"{a:<10}{q50:>9.3f}   [{q25:6.3f}, {q75:6.3f}]{min(best[a]):>9.3f}"
            f"{max(best[a]):>9.3f}{rate:>10.1f}{rules:>12g}"
        )

    first = min(r.history_evaluations[0] for r in runs)
    marks = sorted(
        {first} | {m for f in (0.25, 0.5, 0.75, 1.0) if (m := round(args.budget * f)) >= first}
    )
    print()
    print("median best fitness (dB) after N evaluations")
    print(f"{'algorithm':<10}" + "".join(f"{m:>10}" for m in marks))
    for a in algorithms:
        cells = [statistics.median(best_at(r, m) for r in by_algorithm[a]) for m in marks]
        print(f"{a:<10}" + "".join(f"{c:>10.3f}" for c in cells))

    tests: dict[str, dict[str, object]] = {}
    if "ofa" in algorithms:
        print()
        print("OFA against each, paired by seed (two-sided Wilcoxon signed-rank)")
        print(f"{'vs':<10}{'median diff dB':>16}{'W/T/L':>10}{'statistic':>11}{'p-value':>10}")
        for a in algorithms:
            if a == "ofa":
                continue
            tests[a] = paired_test(best["ofa"], best[a])
            t = tests[a]
            statistic = "n/a" if t["statistic"] is None else f"{t['statistic']:g}"
            p_value = "n/a" if t["p_value"] is None else f"{t['p_value']:.4f}"
            print(
                f"{a:<10}{t['median_difference_db']:>16.4f}"
                f"{str(t['wins']) + '/' + str(t['ties']) + '/' + str(t['losses']):>10}"
                f"{statistic:>11}{p_value:>10}"
            )

    record = {
        "machine": machine_record(),
        "scenario": str(args.scenario),
        "budget": args.budget,
        "duration_s": args.duration,
        "fitness_window_start_s": reference.fitness_window_start_s,
        "noise_seed": reference.seed,
        "seeds": seeds,
        "jobs": args.jobs,
        "ray": None
        if args.ray is None
        else {
            "address": args.ray,
            "cluster": where,
            "local_wall_time_s": local_wall_s,
            "runs_differing_from_local": None if local_wall_s is None else len(differing),
        },
        "wall_time_s": total_wall_s,
        "table2_fitness_db": float(reference.fitness_db[0]),
        "runs": [asdict(r) for r in runs],
        "wilcoxon_ofa_vs": tests,
    }
    args.json_path.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    figure_path = args.figure or args.json_path.with_suffix(".png")
    grid = np.linspace(0, args.budget, 101)
    curves = [
        ConvergenceCurve(
            a,
            grid,
            np.array(
                [statistics.median(best_at(r, int(g)) for r in by_algorithm[a]) for g in grid]
            ),
        )
        for a in algorithms
    ]
    write_convergence_figure(
        figure_path,
        curves,
        f"{scenario.name}: median of {len(seeds)} seeds, {args.duration:g} s evaluations",
        float(reference.fitness_db[0]),
    )
    print()
    print(f"wrote {args.json_path} and {figure_path}")


if __name__ == "__main__":
    main()

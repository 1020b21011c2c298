"""The tuner's optimisers against two published implementations on standard functions.

Not a test: prints tables, with the machine and the date. OFA, FA, GA and PSO
(:data:`services.tuner.registry.ALGORITHMS`) run next to niapy's ``FireflyAlgorithm`` and
pyswarms' ``GlobalBestPSO`` on sphere, Rastrigin, Rosenbrock and Ackley
(:mod:`services.tuner.benchmark_functions`, searched on the unit box [0, 1]^D and mapped to
each function's usual domain) in 10 and 30 dimensions, every run at the same evaluation
budget (``--evaluations-per-dim`` x D) and population (40), over ``--seeds`` seeds.

The peers keep their own defaults apart from the population: niapy's FA (alpha 1, beta0 1,
gamma 0.01, theta 0.97) evaluates after every single move, so its generations are fewer for the
same budget; pyswarms runs budget / 40 iterations with the inertia and acceleration constants
our PSO uses (w 0.7298, c1 = c2 = 1.49618) and its default boundary handling.

Tables: the median (and interquartile range) of the best cost per algorithm and problem (the
global minimum of every function is 0), the mean rank of each algorithm over the problems,
and evaluations per second. niapy and pyswarms are not project dependencies; without them the
script says how to install them and leaves their columns out.

    .venv/bin/python bench/optimiser_peers.py [--seeds 5] [--evaluations-per-dim 500]
        [--dims 10 30] [--functions sphere rastrigin rosenbrock ackley]
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import statistics
import time
from collections.abc import Callable
from importlib.util import find_spec
from pathlib import Path

import numpy as np
from arguments import positive_int
from machine import machine_lines
from scipy.stats import rankdata

from services.tuner.benchmark_functions import BENCHMARK_FUNCTIONS
from services.tuner.evaluation import FloatArray
from services.tuner.registry import ALGORITHMS

PYSWARMS_LOG_DIR = Path(__file__).resolve().parents[1] / "runs" / "bench"
"""pyswarms writes report.log into the working directory; it is kept here instead."""

POPULATION = 40
Runner = Callable[[Callable[[FloatArray], FloatArray], int, int, int], float]
"""(batched function, dimension, budget, seed) -> best cost found."""


def ours(name: str) -> Runner:
    def run(
        function: Callable[[FloatArray], FloatArray], dim: int, budget: int, seed: int
    ) -> float:
        return ALGORITHMS[name](function, dim, budget, seed).best_cost

    return run


def niapy_firefly(
    function: Callable[[FloatArray], FloatArray], dim: int, budget: int, seed: int
) -> float:
    from niapy.algorithms.basic import FireflyAlgorithm
    from niapy.problems import Problem
    from niapy.task import Task

    class UnitBox(Problem):
        def __init__(self) -> None:
            super().__init__(dim, 0.0, 1.0)

        def _evaluate(self, x: FloatArray) -> float:
            return float(function(np.asarray(x, dtype=np.float64)[np.newaxis, :])[0])

    task = Task(problem=UnitBox(), max_evals=budget)
    algorithm = FireflyAlgorithm(population_size=POPULATION, seed=seed)
    _, best_cost = algorithm.run(task)
    if task.evals > budget:
        raise RuntimeError(f"niapy spent {task.evals} evaluations of a budget of {budget}")
    return float(best_cost)


def pyswarms_global_best(
    function: Callable[[FloatArray], FloatArray], dim: int, budget: int, seed: int
) -> float:
    np.random.seed(seed)  # noqa: NPY002 - pyswarms draws from NumPy's global generator
    PYSWARMS_LOG_DIR.mkdir(parents=True, exist_ok=True)
    with contextlib.chdir(PYSWARMS_LOG_DIR):  # its import and its optimisers open report.log
        import pyswarms

        optimiser = pyswarms.single.GlobalBestPSO(
            n_particles=POPULATION,
            dimensions=dim,
            options={"c1": 1.49618, "c2": 1.49618, "w": 0.7298},
            bounds=(np.zeros(dim), np.ones(dim)),
        )
    best_cost, _ = optimiser.optimize(function, iters=budget // POPULATION, verbose=False)
    return float(best_cost)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=positive_int, default=5)
    parser.add_argument("--evaluations-per-dim", type=positive_int, default=500)
    parser.add_argument("--dims", type=positive_int, nargs="+", default=[10, 30])
    parser.add_argument(
        "--functions", nargs="+", default=list(BENCHMARK_FUNCTIONS), choices=BENCHMARK_FUNCTIONS
    )
    args = parser.parse_args()

    runners: dict[str, Runner] = {name: ours(name) for name in ("ofa", "fa", "ga", "pso")}
    missing = [package for package in ("niapy", "pyswarms") if find_spec(package) is None]
    if "niapy" not in missing:
        runners["niapy-FA"] = niapy_firefly
    if "pyswarms" not in missing:
        logging.getLogger("pyswarms").setLevel(logging.WARNING)
        runners["pyswarms-PSO"] = pyswarms_global_best

    for line in machine_lines():
        print(line)
    if missing:
        print(
            f"# {' and '.join(missing)} not installed: their columns are left out. Install them "
            f"into the project's environment with `.venv/bin/pip install {' '.join(missing)}`"
        )
    print(
        f"# budget {args.evaluations_per_dim} x D evaluations, population {POPULATION}, "
        f"seeds 0..{args.seeds - 1}; best cost (global minimum 0), median [q25, q75]"
    )
    problems = [(f, d) for d in args.dims for f in args.functions]
    medians: dict[str, list[float]] = {name: [] for name in runners}
    elapsed_s = dict.fromkeys(runners, 0.0)
    evaluations = dict.fromkeys(runners, 0)
    width = 30
    print()
    print(f"{'problem':<16}" + "".join(f"{name:>{width}}" for name in runners))
    for function_name, dim in problems:
        function = BENCHMARK_FUNCTIONS[function_name]
        budget = args.evaluations_per_dim * dim
        cells = []
        for name, runner in runners.items():
            costs = []
            for seed in range(args.seeds):
                start = time.perf_counter()
                costs.append(runner(function, dim, budget, seed))
                elapsed_s[name] += time.perf_counter() - start
                evaluations[name] += budget
            q25, q50, q75 = np.percentile(costs, [25, 50, 75])
            medians[name].append(float(q50))
            cells.append(f"{q50:.2e} [{q25:.1e}, {q75:.1e}]")
        print(f"{function_name + '-' + str(dim):<16}" + "".join(f"{c:>{width}}" for c in cells))

    ranks = np.array([rankdata([medians[n][k] for n in runners]) for k in range(len(problems))])
    print()
    print(f"{'':<16}" + "".join(f"{name:>{width}}" for name in runners))
    print(f"{'mean rank':<16}" + "".join(f"{r:>{width}.2f}" for r in np.mean(ranks, axis=0)))
    print(
        f"{'evaluations/s':<16}"
        + "".join(f"{evaluations[n] / elapsed_s[n]:>{width}.0f}" for n in runners)
    )
    print(
        f"{'median best':<16}"
        + "".join(f"{statistics.median(medians[n]):>{width}.2e}" for n in runners)
    )


if __name__ == "__main__":
    main()

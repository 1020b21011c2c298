"""The tuner's algorithms behind one signature, for equal-budget comparisons (Fig. 14).

``ALGORITHMS[name](objective, dim, budget, seed, checkpoint_path=None, progress=None)``
runs OFA, plain FA, GA, PSO or pure random search (the baseline all of them must beat)
with its default parameters from an integer seed.
The keyword ``checkpoint_every`` (generations between checkpoints, default 10)
is accepted by all of them as well.
"""

from __future__ import annotations

import os
from typing import Protocol

import numpy as np

from services.tuner.baselines import GeneticAlgorithm, ParticleSwarm
from services.tuner.evaluation import Objective, ProgressCallback
from services.tuner.firefly import FireflyAlgorithm
from services.tuner.generational import PopulationAlgorithm, run_population_algorithm
from services.tuner.ofa import OrthogonalFireflyAlgorithm
from services.tuner.random_search import RandomSearch
from services.tuner.result import OptimisationResult


class AlgorithmRunner(Protocol):
    """Uniform entry point of every registered algorithm."""

    def __call__(
        self,
        objective: Objective,
        dim: int,
        budget: int,
        seed: int,
        checkpoint_path: str | os.PathLike[str] | None = None,
        progress: ProgressCallback | None = None,
        *,
        checkpoint_every: int = 10,
    ) -> OptimisationResult: ...


def seeded_runner(algorithm: PopulationAlgorithm) -> AlgorithmRunner:
    """``algorithm`` run by :func:`run_population_algorithm` from an integer seed."""

    def run(
        objective: Objective,
        dim: int,
        budget: int,
        seed: int,
        checkpoint_path: str | os.PathLike[str] | None = None,
        progress: ProgressCallback | None = None,
        *,
        checkpoint_every: int = 10,
    ) -> OptimisationResult:
        return run_population_algorithm(
            algorithm,
            objective,
            dim,
            budget,
            np.random.default_rng(seed),
            checkpoint_path=checkpoint_path,
            checkpoint_every=checkpoint_every,
            progress=progress,
        )

    return run


ALGORITHMS: dict[str, AlgorithmRunner] = {
    "ofa": seeded_runner(OrthogonalFireflyAlgorithm()),  # Taguchi-chosen FA + eq. 5
    "fa": seeded_runner(FireflyAlgorithm()),  # untuned FA, no mutation
    "ga": seeded_runner(GeneticAlgorithm()),
    "pso": seeded_runner(ParticleSwarm()),
    "random": seeded_runner(RandomSearch()),  # uniform draws, batches of 40
}

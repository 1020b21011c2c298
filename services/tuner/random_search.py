"""Pure random search: the baseline every optimiser of Fig. 14 has to beat at equal budget.

Each generation draws ``population_size`` fresh candidates uniformly in [0, 1]^D and
evaluates them as one batch; nothing is learnt from earlier batches. The generation loop
(:mod:`services.tuner.generational`) keeps the best candidate seen and the convergence
history, enforces the budget (the last batch is truncated) and checkpoints the run, as for
OFA, FA, GA and PSO, so a run is deterministic per seed and resumes bit for bit.

With a budget of B evaluations the best of B uniform draws is what any search that
exploits structure must improve on; on a shallow objective such as eq. 16 of the paper
scenario that is a demanding reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from services.tuner.evaluation import EvaluationBudget
from services.tuner.generational import ParametrisedAlgorithm, Population, replace_evaluated


@dataclass(frozen=True)
class RandomSearchParameters:
    """Batch size per generation (the same 40 as the other algorithms' populations)."""

    population_size: int = 40
    n_generations: int | None = None

    def __post_init__(self) -> None:
        if self.population_size < 1:
            raise ValueError(f"population_size must be at least 1, got {self.population_size}")
        if self.n_generations is not None and self.n_generations < 0:
            raise ValueError(f"n_generations must be non-negative, got {self.n_generations}")


DEFAULT_RANDOM_SEARCH_PARAMETERS = RandomSearchParameters()


@dataclass(frozen=True)
class RandomSearch(ParametrisedAlgorithm):
    """Uniform random sampling of the unit box, one batch per generation."""

    params: RandomSearchParameters = DEFAULT_RANDOM_SEARCH_PARAMETERS

    name: ClassVar[str] = "random"

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        candidates = rng.random(population.positions.shape)
        positions, costs, _ = replace_evaluated(
            population.positions, population.costs, candidates, budget
        )
        return Population(positions, costs)

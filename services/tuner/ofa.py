"""Orthogonal firefly algorithm (OFA): FA (eqs. 1-4) + rank mutation (eq. 5) + Taguchi design.

One OFA generation:

1. move every firefly toward every brighter one with a cooled random step
   (eqs. 1-4, :mod:`services.tuner.firefly`);
2. mutate the moved fireflies with the rank-based probabilities of eq. 5,
   ranked by the costs they had before moving (the costs known at that point),
   never touching the firefly that was best (:mod:`services.tuner.rank_mutation`);
3. evaluate the whole new population as one batch.

The FA parameters are the ones a Taguchi design (Table 1,
:mod:`services.tuner.taguchi`) picks; :func:`make_ofa_trial` is the trial
function such a design runs, and :func:`ofa_parameters_from_design` turns the
design's choice into parameters for :class:`OrthogonalFireflyAlgorithm`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from services.tuner.evaluation import EvaluationBudget, Objective
from services.tuner.firefly import FireflyParameters, firefly_move, firefly_parameters_from_settings
from services.tuner.generational import (
    ParametrisedAlgorithm,
    Population,
    replace_evaluated,
    run_population_algorithm,
)
from services.tuner.rank_mutation import (
    DEFAULT_RANK_MUTATION,
    RankMutationParameters,
    rank_mutate,
)
from services.tuner.taguchi import TaguchiResult, TrialFunction

OFA_FIREFLY_PARAMETERS = FireflyParameters(
    alpha0=0.2, beta0=0.5, gamma=0.7, delta=0.96, population_size=40, n_generations=None
)
"""Default OFA parameters.

alpha0, beta0, gamma and delta are the levels that a Table 1 design
(``taguchi_design(make_ofa_trial(f, 10), table1_factors(0.25), 3, rng)``) chose
on each of the 10-D sphere, Rastrigin, Ackley and Rosenbrock functions; all four
designs agreed. P is 40, the population of the other algorithms, for a
like-for-like comparison, and N_fa is None so that the budget alone ends a run.
For the formation controller, run the design on the eq. 16 objective and use
:func:`ofa_parameters_from_design`.
"""


@dataclass(frozen=True)
class OFAParameters:
    """FA parameters (normally chosen by a Taguchi design) and the eq. 5 mutation bounds."""

    firefly: FireflyParameters = OFA_FIREFLY_PARAMETERS
    mutation: RankMutationParameters = DEFAULT_RANK_MUTATION

    @property
    def population_size(self) -> int:
        return self.firefly.population_size

    @property
    def n_generations(self) -> int | None:
        return self.firefly.n_generations


DEFAULT_OFA_PARAMETERS = OFAParameters()


@dataclass(frozen=True)
class OrthogonalFireflyAlgorithm(ParametrisedAlgorithm):
    """The OFA generation step (move, mutate, evaluate) for the shared generation loop."""

    params: OFAParameters = DEFAULT_OFA_PARAMETERS

    name: ClassVar[str] = "ofa"

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        moved = firefly_move(
            population.positions, population.costs, self.params.firefly, generation, rng
        )
        candidates = rank_mutate(moved, population.costs, self.params.mutation, rng)
        positions, costs, _ = replace_evaluated(
            population.positions, population.costs, candidates, budget
        )
        return Population(positions, costs)


def make_ofa_trial(
    objective: Objective,
    dim: int,
    mutation: RankMutationParameters = DEFAULT_RANK_MUTATION,
) -> TrialFunction:
    """A Taguchi trial: run the OFA at the trial's Table 1 settings, return its best cost.

    The settings name the :class:`FireflyParameters` fields (as
    :func:`~services.tuner.taguchi.table1_factors` does). Each trial spends
    P (N_fa + 1) evaluations: the initial population and N_fa generations.
    """

    def run_trial(settings: Mapping[str, float], seed: int) -> float:
        firefly = firefly_parameters_from_settings(settings)
        budget = firefly.population_size * (int(settings["n_generations"]) + 1)
        result = run_population_algorithm(
            OrthogonalFireflyAlgorithm(OFAParameters(firefly, mutation)),
            objective,
            dim,
            budget,
            np.random.default_rng(seed),
        )
        return result.best_cost

    return run_trial


def ofa_parameters_from_design(
    design: TaguchiResult,
    mutation: RankMutationParameters = DEFAULT_RANK_MUTATION,
    *,
    run_until_budget_spent: bool = True,
) -> OFAParameters:
    """OFA parameters at the levels a Taguchi design chose.

    With ``run_until_budget_spent`` the chosen N_fa is dropped so that a run is
    limited by its evaluation budget only (what an equal-budget comparison needs).
    """
    firefly = firefly_parameters_from_settings(design.chosen_settings)
    if run_until_budget_spent:
        firefly = replace(firefly, n_generations=None)
    return OFAParameters(firefly, mutation)

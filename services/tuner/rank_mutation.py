"""Rank-based mutation of the OFA, eq. 5.

Eq. 5 gives individual i the mutation probability

    P_i = P_min + rank(i) / P * (P_max - P_min) * F_ave / F(i)

with rank 1 for the best individual and P the population size. Read with a
fitness F that is positive and larger for better individuals, both factors grow
from the best individual to the worst: rank(i) / P rises from 1/P to 1, and
F_ave / F(i), the individual's shortfall relative to the population average,
rises past 1 for individuals worse than average. Good individuals are kept,
poor ones are sent exploring.

The tuner minimises a positive cost c instead. Substituting F = c literally
would invert the second factor (the worst individual would have the smallest
F_ave / F(i)) and make the best individual the most likely to mutate. The
reading used here keeps the paper's intent: the relative shortfall is
c(i) / c_ave, which equals F_ave / F(i) for the fitness F = 1 / c when F_ave is
taken as the fitness of the average cost. So

    P_i = clip(P_min + rank(i) / P * (P_max - P_min) * c(i) / c_ave, P_min, P_max)

with rank(i) = 1 + the number of individuals with a strictly lower cost (tied
costs share a rank). Without the clip, P_i could exceed P_max (any individual
worse than average near the bottom of the ranking) or 1; DESIGN §6 asks for the
clip. This reading guarantees:

* P_min <= P_i <= P_max for every individual;
* c(i) <= c(k) implies P_i <= P_k: a worse individual never mutates less
  than a better one, and equal costs mutate with equal probability.

Mutation operator: a selected individual has each gene reset to a uniform
draw in [0, 1] with probability ``gene_reset_probability`` (default 1/D), and
always at least one gene; uniform resets explore the whole range, which is
what mutation is for in the paper. The current best individual is never
mutated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.tuner.evaluation import FloatArray, IntArray


@dataclass(frozen=True)
class RankMutationParameters:
    """Bounds of eq. 5 and the per-gene reset probability (None: 1/D)."""

    p_min: float = 0.02
    p_max: float = 0.3
    gene_reset_probability: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.p_min <= self.p_max <= 1.0:
            raise ValueError(
                f"need 0 <= p_min <= p_max <= 1, got p_min={self.p_min}, p_max={self.p_max}"
            )
        reset = self.gene_reset_probability
        if reset is not None and not 0.0 <= reset <= 1.0:
            raise ValueError(f"gene_reset_probability must lie in [0, 1], got {reset}")


DEFAULT_RANK_MUTATION = RankMutationParameters()


def competition_ranks(costs: FloatArray) -> IntArray:
    """rank(i) = 1 + number of strictly lower costs: 1 is the best, ties share a rank."""
    sorted_costs = np.sort(costs)
    ranks: IntArray = np.searchsorted(sorted_costs, costs, side="left").astype(np.int64) + 1
    return ranks


def mutation_probabilities(costs: FloatArray, p_min: float, p_max: float) -> FloatArray:
    """Eq. 5 with costs, clipped to [p_min, p_max] (see the module docstring)."""
    if costs.ndim != 1 or costs.size == 0:
        raise ValueError(f"costs must be a non-empty 1-D array, got shape {costs.shape}")
    if not np.all(np.isfinite(costs)) or np.any(costs <= 0.0):
        raise ValueError("eq. 5 needs strictly positive, finite costs")
    rank_fraction = competition_ranks(costs) / costs.size
    relative_shortfall = costs / np.mean(costs)
    probabilities: FloatArray = np.clip(
        p_min + rank_fraction * (p_max - p_min) * relative_shortfall, p_min, p_max
    )
    return probabilities


def rank_mutate(
    positions: FloatArray,
    costs: FloatArray,
    params: RankMutationParameters,
    rng: np.random.Generator,
) -> FloatArray:
    """Mutate individuals with the probabilities of eq. 5; the lowest-cost one is spared.

    ``positions`` (P, D) are the individuals to mutate and ``costs`` (P,) the
    costs that rank them. Returns a new array; the random draws do not depend
    on which individuals are selected.
    """
    n_individuals, dim = positions.shape
    if costs.shape != (n_individuals,):
        raise ValueError(f"costs shape {costs.shape} does not match {n_individuals} individuals")
    gene_probability = (
        1.0 / dim if params.gene_reset_probability is None else params.gene_reset_probability
    )
    selected = rng.random(n_individuals) < mutation_probabilities(costs, params.p_min, params.p_max)
    selected[int(np.argmin(costs))] = False
    reset_genes = rng.random((n_individuals, dim)) < gene_probability
    reset_genes[np.arange(n_individuals), rng.integers(0, dim, size=n_individuals)] = True
    reset_values = rng.random((n_individuals, dim))
    mutated: FloatArray = np.where(reset_genes & selected[:, np.newaxis], reset_values, positions)
    return mutated

"""The outcome of one optimisation run: best candidate and convergence history.

The history holds, per generation, the number of evaluations spent so far and the
best cost found so far, which is what Fig. 14 plots (as fitness, eq. 16) when the
algorithms are compared at an equal evaluation budget.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.tuner.evaluation import FloatArray, IntArray, snr_fitness_from_cost


@dataclass(frozen=True)
class ConvergenceHistory:
    """Best cost so far after each generation; generation 0 is the initial population."""

    n_evaluations: IntArray
    best_cost: FloatArray

    def __post_init__(self) -> None:
        if self.n_evaluations.shape != self.best_cost.shape or self.n_evaluations.ndim != 1:
            raise ValueError("history arrays must be one-dimensional and of equal length")

    @property
    def best_fitness_db(self) -> FloatArray:
        """Best SNR fitness so far, -10 log10(best cost) (eq. 16)."""
        return snr_fitness_from_cost(self.best_cost)


@dataclass(frozen=True)
class OptimisationResult:
    """Best normalised candidate found, its cost, and how the search got there."""

    algorithm: str
    best_x: FloatArray
    best_cost: float
    n_evaluations: int
    n_generations: int
    history: ConvergenceHistory

    @property
    def best_fitness_db(self) -> float:
        """SNR fitness of the best candidate, -10 log10(best cost) (eq. 16)."""
        return float(snr_fitness_from_cost(self.best_cost))

    def same_as(self, other: OptimisationResult) -> bool:
        """True when both runs produced bit-identical results (used for determinism checks)."""
        return (
            self.algorithm == other.algorithm
            and np.array_equal(self.best_x, other.best_x)
            and self.best_cost == other.best_cost
            and self.n_evaluations == other.n_evaluations
            and self.n_generations == other.n_generations
            and np.array_equal(self.history.n_evaluations, other.history.n_evaluations)
            and np.array_equal(self.history.best_cost, other.history.best_cost)
        )

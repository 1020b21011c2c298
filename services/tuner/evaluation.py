"""Objective evaluation under a fixed budget, and the SNR fitness of eq. 16.

Every optimiser in this package searches the unit box [0, 1]^D and minimises a
positive cost. The objective is called with a whole population at once, a batch
``X`` of shape (P, D), and returns costs of shape (P,). An
:class:`EvaluationBudget` counts evaluated rows so that different algorithms can
be compared at exactly the same number of evaluations: a batch that would
overrun the budget is truncated, never evaluated in full.

The paper scores a candidate with an SNR, eq. 16 (and eq. 8 for model fitting):
fitness = -10 log10(cost), which is maximised. Minimising the cost and
maximising that fitness are the same search; :func:`snr_fitness_from_cost`
converts one to the other for reports and plots (Fig. 14).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

Objective = Callable[[FloatArray], FloatArray]
"""Maps a batch of normalised candidates, shape (P, D), to positive costs, shape (P,)."""

ProgressCallback = Callable[[int, int, float], None]
"""Called once per generation with (generation, n_evaluations, best_cost)."""


def snr_fitness_from_cost(cost: ArrayLike) -> FloatArray:
    """Return the paper's SNR fitness -10 log10(cost) in dB (eq. 16), to be maximised.

    Raises ValueError when a cost is not strictly positive and finite, since the
    logarithm is then undefined or meaningless.
    """
    cost_array = np.asarray(cost, dtype=np.float64)
    if not np.all(np.isfinite(cost_array)) or np.any(cost_array <= 0.0):
        raise ValueError("SNR fitness needs strictly positive, finite costs")
    fitness_db: FloatArray = -10.0 * np.log10(cost_array)
    return fitness_db


class EvaluationBudget:
    """Counts objective evaluations (rows) and refuses to exceed ``max_evaluations``.

    The objective receives a copy of the accepted rows, so it cannot alter the
    optimiser's population. Returned costs are checked: shape (rows,), finite and
    strictly positive, as the SNR fitness and eq. 5 both require.
    """

    def __init__(self, objective: Objective, max_evaluations: int, n_evaluations: int = 0) -> None:
        if max_evaluations < 1:
            raise ValueError(f"max_evaluations must be at least 1, got {max_evaluations}")
        if not 0 <= n_evaluations <= max_evaluations:
            raise ValueError(
                f"n_evaluations must lie in [0, {max_evaluations}], got {n_evaluations}"
            )
        self._objective = objective
        self.max_evaluations = max_evaluations
        self.n_evaluations = n_evaluations

    @property
    def remaining(self) -> int:
        """Evaluations still allowed."""
        return self.max_evaluations - self.n_evaluations

    @property
    def exhausted(self) -> bool:
        """True once every allowed evaluation has been spent."""
        return self.remaining == 0

    def evaluate(self, candidates: FloatArray) -> FloatArray:
        """Evaluate the leading rows of ``candidates`` that fit in the budget, in one call.

        Returns the costs of the evaluated rows only; its length is
        ``min(len(candidates), remaining)`` and may be zero, in which case the
        objective is not called.
        """
        if candidates.ndim != 2:
            raise ValueError(f"candidates must have shape (P, D), got {candidates.shape}")
        n_rows = min(candidates.shape[0], self.remaining)
        if n_rows == 0:
            return np.empty(0, dtype=np.float64)
        batch = np.array(candidates[:n_rows], dtype=np.float64, copy=True)
        costs = np.asarray(self._objective(batch), dtype=np.float64)
        if costs.shape != (n_rows,):
            raise ValueError(
                f"objective returned shape {costs.shape} for a batch of {n_rows} rows; "
                f"expected ({n_rows},)"
            )
        if not np.all(np.isfinite(costs)) or np.any(costs <= 0.0):
            raise ValueError(
                "objective must return strictly positive, finite costs "
                "(return a large finite penalty for a failed candidate)"
            )
        self.n_evaluations += n_rows
        return costs

"""Evaluation budget and the SNR fitness of eq. 16."""

import numpy as np
import pytest

from services.tuner.evaluation import EvaluationBudget, snr_fitness_from_cost


def test_snr_fitness_is_minus_ten_log10_of_the_cost() -> None:
    np.testing.assert_allclose(snr_fitness_from_cost([1.0, 0.01, 10.0]), [0.0, 20.0, -10.0])
    assert float(snr_fitness_from_cost(1e-12)) == pytest.approx(120.0)


def test_snr_fitness_refuses_non_positive_costs() -> None:
    with pytest.raises(ValueError):
        snr_fitness_from_cost([1.0, 0.0])
    with pytest.raises(ValueError):
        snr_fitness_from_cost(-1.0)


def test_budget_truncates_the_last_batch_and_then_stops_calling() -> None:
    batch_sizes: list[int] = []

    def objective(candidates: np.ndarray) -> np.ndarray:
        batch_sizes.append(candidates.shape[0])
        return np.ones(candidates.shape[0])

    budget = EvaluationBudget(objective, 25)
    assert budget.evaluate(np.zeros((10, 2))).shape == (10,)
    assert budget.evaluate(np.zeros((10, 2))).shape == (10,)
    assert budget.evaluate(np.zeros((10, 2))).shape == (5,)
    assert budget.exhausted
    assert budget.evaluate(np.zeros((10, 2))).shape == (0,)
    assert batch_sizes == [10, 10, 5]
    assert budget.n_evaluations == 25


def test_objective_cannot_alter_the_callers_candidates() -> None:
    def vandal(candidates: np.ndarray) -> np.ndarray:
        candidates[:] = -1.0
        return np.ones(candidates.shape[0])

    candidates = np.full((4, 2), 0.5)
    EvaluationBudget(vandal, 10).evaluate(candidates)
    np.testing.assert_array_equal(candidates, 0.5)

"""Random search, the equal-budget baseline: budget, seeding, and what it evaluates."""

import numpy as np
import pytest

from services.tuner.benchmark_functions import sphere
from services.tuner.evaluation import FloatArray
from services.tuner.random_search import RandomSearchParameters
from services.tuner.registry import ALGORITHMS


class RecordingObjective:
    """Sphere that keeps every candidate it was asked to evaluate, in order."""

    def __init__(self) -> None:
        self.batches: list[FloatArray] = []

    def __call__(self, candidates: FloatArray) -> FloatArray:
        self.batches.append(candidates.copy())
        return sphere(candidates)


@pytest.mark.parametrize("budget", [1, 39, 40, 41, 123])
def test_random_search_spends_exactly_its_budget_on_the_seeded_uniform_stream(budget: int) -> None:
    objective = RecordingObjective()
    result = ALGORITHMS["random"](objective, 6, budget, 11)
    evaluated = np.concatenate(objective.batches)
    assert result.n_evaluations == budget
    assert evaluated.shape == (budget, 6)
    assert all(batch.shape[0] <= 40 for batch in objective.batches)
    # The evaluated candidates are the first `budget` rows the seed's generator draws: fresh
    # uniform batches, nothing reused or learnt; the best is the best of those rows.
    expected = np.random.default_rng(11).random((budget, 6))
    np.testing.assert_array_equal(evaluated, expected)
    assert result.best_cost == sphere(expected).min()
    np.testing.assert_array_equal(result.best_x, expected[np.argmin(sphere(expected))])


def test_random_search_is_deterministic_per_seed() -> None:
    first = ALGORITHMS["random"](sphere, 16, 200, 3)
    again = ALGORITHMS["random"](sphere, 16, 200, 3)
    other = ALGORITHMS["random"](sphere, 16, 200, 4)
    assert first.same_as(again)
    assert not np.array_equal(first.best_x, other.best_x)


def test_random_search_rejects_an_empty_batch() -> None:
    with pytest.raises(ValueError, match="population_size"):
        RandomSearchParameters(population_size=0)

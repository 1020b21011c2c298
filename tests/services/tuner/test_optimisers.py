"""Shared contract of every registered optimiser: budget, batching, seeding, history."""

import numpy as np
import pytest

from services.tuner.benchmark_functions import rastrigin, sphere
from services.tuner.evaluation import FloatArray
from services.tuner.registry import ALGORITHMS

ALGORITHM_NAMES = sorted(ALGORITHMS)
OPTIMISER_NAMES = [name for name in ALGORITHM_NAMES if name != "random"]
"""The algorithms that learn from earlier evaluations, unlike the random-search baseline."""


class CountingObjective:
    """Rastrigin that records the size of every batch it is given."""

    def __init__(self) -> None:
        self.batch_sizes: list[int] = []

    def __call__(self, candidates: FloatArray) -> FloatArray:
        assert candidates.ndim == 2
        assert np.all((candidates >= 0.0) & (candidates <= 1.0))
        self.batch_sizes.append(candidates.shape[0])
        return rastrigin(candidates)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
@pytest.mark.parametrize("budget", [1003, 7, 1])
def test_budget_is_spent_exactly_with_one_batch_per_generation(name: str, budget: int) -> None:
    objective = CountingObjective()
    result = ALGORITHMS[name](objective, 4, budget, 0)
    assert result.algorithm == name
    assert sum(objective.batch_sizes) == budget
    assert result.n_evaluations == budget
    assert len(objective.batch_sizes) == result.n_generations + 1
    assert result.history.n_evaluations[-1] == budget


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_same_seed_gives_identical_results_and_other_seeds_differ(name: str) -> None:
    first = ALGORITHMS[name](rastrigin, 5, 600, 42)
    again = ALGORITHMS[name](rastrigin, 5, 600, 42)
    other = ALGORITHMS[name](rastrigin, 5, 600, 43)
    assert first.same_as(again)
    assert not first.same_as(other)
    assert not np.array_equal(first.best_x, other.best_x)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_results_do_not_depend_on_or_touch_global_random_state(name: str) -> None:
    saved_global_state = np.random.get_state()  # noqa: NPY002 - the legacy global state is the subject
    try:
        np.random.seed(1)  # noqa: NPY002
        first = ALGORITHMS[name](sphere, 3, 300, 7)
        np.random.seed(2)  # noqa: NPY002
        before = np.random.random(3)  # noqa: NPY002
        np.random.seed(2)  # noqa: NPY002
        second = ALGORITHMS[name](sphere, 3, 300, 7)
        after = np.random.random(3)  # noqa: NPY002
    finally:
        np.random.set_state(saved_global_state)  # noqa: NPY002
    assert first.same_as(second)
    np.testing.assert_array_equal(before, after)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_history_is_monotone_and_ends_at_the_best(name: str) -> None:
    result = ALGORITHMS[name](rastrigin, 4, 800, 3)
    history = result.history
    assert len(history.best_cost) == result.n_generations + 1
    assert np.all(np.diff(history.n_evaluations) > 0)
    assert np.all(np.diff(history.best_cost) <= 0.0)
    assert history.best_cost[-1] == result.best_cost
    assert np.all((result.best_x >= 0.0) & (result.best_x <= 1.0))
    assert rastrigin(result.best_x[np.newaxis, :])[0] == result.best_cost
    np.testing.assert_allclose(history.best_fitness_db, -10.0 * np.log10(history.best_cost))


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_progress_is_reported_once_per_generation(name: str) -> None:
    calls: list[tuple[int, int, float]] = []
    result = ALGORITHMS[name](sphere, 3, 500, 5, progress=lambda g, n, c: calls.append((g, n, c)))
    assert [generation for generation, _, _ in calls] == list(range(result.n_generations + 1))
    assert [n for _, n, _ in calls] == result.history.n_evaluations.tolist()
    assert [cost for _, _, cost in calls] == result.history.best_cost.tolist()


@pytest.mark.parametrize("name", OPTIMISER_NAMES)
def test_every_algorithm_beats_random_search_tenfold_at_equal_budget(name: str) -> None:
    budget = 2000
    random_search_best = sphere(np.random.default_rng(0).random((budget, 5))).min()
    result = ALGORITHMS[name](sphere, 5, budget, 0)
    assert result.best_cost < 0.1 * random_search_best


def test_objective_returning_the_wrong_shape_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="shape"):
        ALGORITHMS["pso"](lambda x: np.ones((x.shape[0], 1)), 3, 100, 0)


def test_objective_returning_a_non_positive_cost_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="positive"):
        ALGORITHMS["ofa"](lambda x: np.zeros(x.shape[0]), 3, 100, 0)

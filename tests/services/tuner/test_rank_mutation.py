"""Rank-based mutation, eq. 5, read with costs (worse individuals mutate more)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from services.tuner.rank_mutation import (
    RankMutationParameters,
    competition_ranks,
    mutation_probabilities,
    rank_mutate,
)

positive_costs = arrays(
    np.float64,
    st.integers(min_value=1, max_value=60),
    elements=st.floats(min_value=1e-12, max_value=1e12, allow_nan=False, allow_infinity=False),
)
probability_bounds = st.tuples(
    st.floats(min_value=0.0, max_value=1.0), st.floats(min_value=0.0, max_value=1.0)
).map(sorted)


@settings(database=None, deadline=None, max_examples=300)
@given(costs=positive_costs, bounds=probability_bounds)
def test_eq5_probabilities_stay_within_bounds(costs: np.ndarray, bounds: list[float]) -> None:
    p_min, p_max = bounds
    probabilities = mutation_probabilities(costs, p_min, p_max)
    assert probabilities.shape == costs.shape
    assert np.all(probabilities >= p_min)
    assert np.all(probabilities <= p_max)


@settings(database=None, deadline=None, max_examples=300)
@given(costs=positive_costs, bounds=probability_bounds)
def test_a_worse_individual_never_gets_a_lower_probability(
    costs: np.ndarray, bounds: list[float]
) -> None:
    probabilities = mutation_probabilities(costs, bounds[0], bounds[1])
    order = np.argsort(costs, kind="stable")
    assert np.all(np.diff(probabilities[order]) >= 0.0)
    # equal costs mutate with equal probability
    for value in np.unique(costs):
        assert np.ptp(probabilities[costs == value]) == 0.0


def test_probabilities_match_hand_computed_eq5() -> None:
    costs = np.array([4.0, 1.0, 3.0, 2.0])
    probabilities = mutation_probabilities(costs, 0.0, 1.0)
    # rank / P * cost / mean(cost) with mean 2.5: 1.6 (clipped to 1), 0.1, 0.9, 0.4
    np.testing.assert_allclose(probabilities, [1.0, 0.25 * 0.4, 0.75 * 1.2, 0.5 * 0.8])
    probabilities = mutation_probabilities(costs, 0.1, 0.5)
    np.testing.assert_allclose(probabilities, [0.5, 0.14, 0.46, 0.26])


def test_ties_share_the_better_rank() -> None:
    np.testing.assert_array_equal(competition_ranks(np.array([2.0, 1.0, 2.0, 5.0])), [2, 1, 2, 4])


def test_eq5_refuses_non_positive_costs() -> None:
    with pytest.raises(ValueError):
        mutation_probabilities(np.array([1.0, 0.0]), 0.1, 0.5)
    with pytest.raises(ValueError):
        mutation_probabilities(np.array([1.0, np.nan]), 0.1, 0.5)


def test_certain_mutation_changes_everyone_but_the_best() -> None:
    rng = np.random.default_rng(3)
    positions = rng.random((30, 6))
    costs = rng.random(30) + 0.1
    best = int(np.argmin(costs))
    always = RankMutationParameters(p_min=1.0, p_max=1.0)
    mutated = rank_mutate(positions, costs, always, rng)
    changed_genes = mutated != positions
    assert not changed_genes[best].any()
    others = np.delete(changed_genes, best, axis=0)
    assert np.all(others.sum(axis=1) >= 1)
    assert np.all((mutated >= 0.0) & (mutated <= 1.0))


def test_zero_probability_mutates_nothing() -> None:
    rng = np.random.default_rng(4)
    positions = rng.random((10, 3))
    never = RankMutationParameters(p_min=0.0, p_max=0.0)
    np.testing.assert_array_equal(
        rank_mutate(positions, rng.random(10) + 1.0, never, rng), positions
    )


def test_worse_half_mutates_more_often_than_better_half() -> None:
    rng = np.random.default_rng(5)
    n_individuals = 40
    costs = np.linspace(1.0, 10.0, n_individuals)
    positions = np.full((n_individuals, 4), 0.5)
    params = RankMutationParameters(p_min=0.05, p_max=0.6)
    mutation_counts = np.zeros(n_individuals)
    for _ in range(200):
        mutation_counts += (rank_mutate(positions, costs, params, rng) != positions).any(axis=1)
    assert mutation_counts[0] == 0
    assert (
        mutation_counts[n_individuals // 2 :].sum()
        > 2 * mutation_counts[: n_individuals // 2].sum()
    )

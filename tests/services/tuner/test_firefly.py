"""Firefly algorithm, eqs. 1-4: attraction, cooling, the sequential move rule, convergence."""

import numpy as np
import pytest

from services.tuner.benchmark_functions import sphere
from services.tuner.firefly import (
    FireflyAlgorithm,
    FireflyParameters,
    attract_toward_brighter,
    firefly_move,
    random_step_scale,
)
from services.tuner.generational import run_population_algorithm


def test_random_step_cools_geometrically_eq4() -> None:
    params = FireflyParameters(alpha0=0.8, delta=0.9)
    assert random_step_scale(params, 0) == pytest.approx(0.8)
    assert random_step_scale(params, 3) == pytest.approx(0.8 * 0.9**3)


def test_delta_outside_unit_interval_is_refused() -> None:
    for delta in (0.0, 1.0, 10.0):
        with pytest.raises(ValueError, match="delta"):
            FireflyParameters(delta=delta)


def test_dimmer_firefly_moves_by_beta0_exp_minus_gamma_r_squared() -> None:
    positions = np.array([[0.2, 0.2], [0.8, 0.6]])
    costs = np.array([1.0, 2.0])
    moved = attract_toward_brighter(positions, costs, beta0=0.7, gamma=2.0)
    squared_distance = 0.6**2 + 0.4**2
    step = 0.7 * np.exp(-2.0 * squared_distance)
    np.testing.assert_allclose(moved[1], positions[1] + step * (positions[0] - positions[1]))
    np.testing.assert_array_equal(moved[0], positions[0])


def test_equally_bright_fireflies_do_not_attract_each_other() -> None:
    positions = np.array([[0.1, 0.9], [0.7, 0.3], [0.5, 0.5]])
    moved = attract_toward_brighter(positions, np.array([1.0, 1.0, 3.0]), beta0=1.0, gamma=1.0)
    np.testing.assert_array_equal(moved[:2], positions[:2])
    assert not np.array_equal(moved[2], positions[2])


def per_firefly_reference(
    positions: np.ndarray, costs: np.ndarray, beta0: float, gamma: float
) -> np.ndarray:
    """Textbook double loop: firefly i moves toward each brighter j, brightest j first."""
    order = np.argsort(costs, kind="stable")
    moved = positions.copy()
    for i in range(positions.shape[0]):
        for j in order:
            if costs[j] < costs[i]:
                r_squared = float(np.sum((moved[i] - positions[j]) ** 2))
                moved[i] = moved[i] + beta0 * np.exp(-gamma * r_squared) * (positions[j] - moved[i])
    return moved


def test_batched_attraction_equals_the_per_firefly_double_loop() -> None:
    rng = np.random.default_rng(11)
    positions = rng.random((25, 4))
    costs = np.round(rng.random(25), 1) + 0.1  # rounding creates ties
    np.testing.assert_allclose(
        attract_toward_brighter(positions, costs, beta0=2.0, gamma=0.5),
        per_firefly_reference(positions, costs, beta0=2.0, gamma=0.5),
        rtol=1e-12,
        atol=1e-12,
    )


def test_moves_stay_in_the_unit_box() -> None:
    rng = np.random.default_rng(2)
    params = FireflyParameters(alpha0=5.0, beta0=5.0, gamma=0.3)
    moved = firefly_move(rng.random((50, 3)), rng.random(50) + 0.1, params, 0, rng)
    assert moved.min() >= 0.0
    assert moved.max() <= 1.0


def test_fa_converges_on_the_5d_sphere() -> None:
    """Random search with the same 3,000 evaluations almost never gets below 0.1.

    A 5-ball of radius sqrt(0.1) fills about 1e-7 of the box [-5.12, 5.12]^5, so
    uniform sampling hits it with probability about 4e-4 in 3,000 draws. The FA
    (alpha cooling to 0.2 * 0.95^149 ~ 1e-4) must get four orders of magnitude
    below that.
    """
    budget = 3000
    params = FireflyParameters(alpha0=0.2, beta0=0.5, gamma=1.0, delta=0.95, population_size=20)
    result = run_population_algorithm(
        FireflyAlgorithm(params), sphere, 5, budget, np.random.default_rng(0)
    )
    random_search_best = sphere(np.random.default_rng(0).random((budget, 5))).min()
    assert random_search_best > 0.1
    assert result.best_cost < 1e-5
    np.testing.assert_allclose(result.best_x, 0.5, atol=2e-3)


def test_fa_stops_after_n_generations() -> None:
    params = FireflyParameters(population_size=10, n_generations=7)
    result = run_population_algorithm(
        FireflyAlgorithm(params), sphere, 3, 10_000, np.random.default_rng(1)
    )
    assert result.n_generations == 7
    assert result.n_evaluations == 10 * 8

"""Benchmark functions: batched, positive, zero (plus offset) at the known optimum."""

import numpy as np
import pytest

from services.tuner.benchmark_functions import BENCHMARK_FUNCTIONS, COST_OFFSET

OPTIMA = {"sphere": 0.5, "rastrigin": 0.5, "ackley": 0.5, "rosenbrock": (1.0 + 2.048) / 4.096}


@pytest.mark.parametrize("name", sorted(BENCHMARK_FUNCTIONS))
def test_minimum_is_the_offset_at_the_known_optimum(name: str) -> None:
    optimum = np.full((1, 6), OPTIMA[name])
    assert BENCHMARK_FUNCTIONS[name](optimum)[0] == pytest.approx(COST_OFFSET, abs=1e-13)


@pytest.mark.parametrize("name", sorted(BENCHMARK_FUNCTIONS))
def test_costs_are_batched_and_strictly_positive(name: str) -> None:
    candidates = np.random.default_rng(0).random((200, 6))
    costs = BENCHMARK_FUNCTIONS[name](candidates)
    assert costs.shape == (200,)
    assert np.all(costs > 0.0)
    optimum = BENCHMARK_FUNCTIONS[name](np.full((1, 6), OPTIMA[name]))[0]
    assert np.all(costs > optimum)
    np.testing.assert_array_equal(costs[:5], BENCHMARK_FUNCTIONS[name](candidates[:5]))


def test_known_values_in_the_usual_domains() -> None:
    corner = np.zeros((1, 2))  # (-5.12, -5.12) for sphere and Rastrigin
    assert BENCHMARK_FUNCTIONS["sphere"](corner)[0] == pytest.approx(2 * 5.12**2)
    assert BENCHMARK_FUNCTIONS["rastrigin"](corner)[0] == pytest.approx(
        20.0 + 2 * (5.12**2 - 10.0 * np.cos(2.0 * np.pi * 5.12))
    )
    # Rosenbrock at (0, 0) in its domain: (1 - 0)^2 = 1
    assert BENCHMARK_FUNCTIONS["rosenbrock"](np.full((1, 2), 0.5))[0] == pytest.approx(1.0)

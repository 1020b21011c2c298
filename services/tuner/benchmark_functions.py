"""Standard test functions for the optimisers, batched and on the normalised box.

Each function takes candidates X of shape (P, D) in [0, 1]^D, maps them
linearly onto the function's usual domain, and returns costs of shape (P,).
The global minimum of each function is 0; every cost gets ``COST_OFFSET``
added so that it is strictly positive, as the SNR fitness -10 log10(cost)
(eq. 16) and the rank mutation (eq. 5) require.

==========  ===================  =====================
function    domain per axis      minimum at
==========  ===================  =====================
sphere      [-5.12, 5.12]        0 (x = 0.5 normalised)
rastrigin   [-5.12, 5.12]        0 (x = 0.5 normalised)
rosenbrock  [-2.048, 2.048]      1 (x = 0.744140625)
ackley      [-32.768, 32.768]    0 (x = 0.5 normalised)
==========  ===================  =====================
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from services.tuner.evaluation import FloatArray

COST_OFFSET = 1e-12


def to_domain(unit_candidates: FloatArray, lower: float, upper: float) -> FloatArray:
    """Map candidates from [0, 1]^D onto [lower, upper]^D."""
    if unit_candidates.ndim != 2:
        raise ValueError(f"candidates must have shape (P, D), got {unit_candidates.shape}")
    mapped: FloatArray = lower + (upper - lower) * unit_candidates
    return mapped


def sphere(unit_candidates: FloatArray) -> FloatArray:
    """sum x_k^2 on [-5.12, 5.12]^D."""
    x = to_domain(unit_candidates, -5.12, 5.12)
    costs: FloatArray = np.sum(x**2, axis=1) + COST_OFFSET
    return costs


def rastrigin(unit_candidates: FloatArray) -> FloatArray:
    """10 D + sum (x_k^2 - 10 cos(2 pi x_k)) on [-5.12, 5.12]^D."""
    x = to_domain(unit_candidates, -5.12, 5.12)
    value = 10.0 * x.shape[1] + np.sum(x**2 - 10.0 * np.cos(2.0 * np.pi * x), axis=1)
    costs: FloatArray = np.maximum(value, 0.0) + COST_OFFSET
    return costs


def rosenbrock(unit_candidates: FloatArray) -> FloatArray:
    """sum 100 (x_{k+1} - x_k^2)^2 + (1 - x_k)^2 on [-2.048, 2.048]^D (D >= 2)."""
    x = to_domain(unit_candidates, -2.048, 2.048)
    if x.shape[1] < 2:
        raise ValueError("Rosenbrock needs at least two dimensions")
    value = np.sum(100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1.0 - x[:, :-1]) ** 2, axis=1)
    costs: FloatArray = value + COST_OFFSET
    return costs


def ackley(unit_candidates: FloatArray) -> FloatArray:
    """-20 exp(-0.2 sqrt(mean x^2)) - exp(mean cos 2 pi x) + 20 + e on [-32.768, 32.768]^D."""
    x = to_domain(unit_candidates, -32.768, 32.768)
    value = (
        -20.0 * np.exp(-0.2 * np.sqrt(np.mean(x**2, axis=1)))
        - np.exp(np.mean(np.cos(2.0 * np.pi * x), axis=1))
        + 20.0
        + np.e
    )
    costs: FloatArray = np.maximum(value, 0.0) + COST_OFFSET
    return costs


BENCHMARK_FUNCTIONS: dict[str, Callable[[FloatArray], FloatArray]] = {
    "sphere": sphere,
    "rastrigin": rastrigin,
    "rosenbrock": rosenbrock,
    "ackley": ackley,
}

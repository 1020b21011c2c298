"""Yang's firefly algorithm (FA), eqs. 1-4, on the normalised box [0, 1]^D.

Brightness is the inverse of cost: a firefly with a lower cost is brighter.

* eq. 2, distance: r_ij = ||x_i - x_j||, evaluated for the whole population
  against one attractor at a time in a single array operation;
* eq. 1, attractiveness: beta(r) = beta0 exp(-gamma r^2);
* eq. 3, movement: each firefly i moves toward every brighter firefly j,
  x_i <- x_i + beta0 exp(-gamma r_ij^2) (x_j - x_i). The paper prints beta in
  front of the exponential; the attractiveness at r = 0 is beta0 (eq. 1), which
  is used here. Then one random step alpha_t eps_i is added, eps_i drawn
  uniformly in [-0.5, 0.5]^D (one draw per firefly and generation, as eq. 3
  indexes it), and positions are clipped to [0, 1];
* eq. 4, cooling: alpha_t = alpha0 delta^t with 0 < delta < 1, t = 0 for the
  first move.

The attractors are the positions at the start of the generation, visited from
brightest to dimmest (Yang's reference code sorts the population by brightness
every generation). A firefly's moves are applied one after another, so each
move's distance is measured from where the previous move left it; this keeps
the attraction a chain of steps toward single fireflies rather than one jump
toward the sum of all of them, which would overshoot when many fireflies are
brighter. Looping over attractors on the outside and moving all dimmer
fireflies at once gives the same positions as looping over fireflies on the
outside. The brightest firefly has no brighter neighbour and only takes its
random step.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from services.tuner.evaluation import EvaluationBudget, FloatArray
from services.tuner.generational import ParametrisedAlgorithm, Population, replace_evaluated


@dataclass(frozen=True)
class FireflyParameters:
    """FA control parameters of Table 1, in the normalised decision space.

    ``n_generations`` (N_fa) counts generations after the initial population;
    None runs until the evaluation budget is spent. The defaults are the
    settings Yang commonly uses for an untuned FA (40 fireflies, alpha0 = 0.2,
    beta0 = 1, gamma = 1, cooling 0.97); the plain-FA baseline runs with them.
    """

    alpha0: float = 0.2
    beta0: float = 1.0
    gamma: float = 1.0
    delta: float = 0.97
    population_size: int = 40
    n_generations: int | None = None

    def __post_init__(self) -> None:
        if self.alpha0 < 0.0:
            raise ValueError(f"alpha0 must be non-negative, got {self.alpha0}")
        if self.beta0 < 0.0:
            raise ValueError(f"beta0 must be non-negative, got {self.beta0}")
        if self.gamma < 0.0:
            raise ValueError(f"gamma must be non-negative, got {self.gamma}")
        if not 0.0 < self.delta < 1.0:
            raise ValueError(f"delta must lie in (0, 1) (eq. 4), got {self.delta}")
        if self.population_size < 2:
            raise ValueError(f"population_size must be at least 2, got {self.population_size}")
        if self.n_generations is not None and self.n_generations < 0:
            raise ValueError(f"n_generations must be non-negative, got {self.n_generations}")


def random_step_scale(params: FireflyParameters, generation: int) -> float:
    """alpha_t = alpha0 delta^t (eq. 4)."""
    return params.alpha0 * params.delta**generation


def attract_toward_brighter(
    positions: FloatArray, costs: FloatArray, beta0: float, gamma: float
) -> FloatArray:
    """Move every firefly toward every brighter one (eqs. 1-3 without the random step).

    ``positions`` has shape (P, D) and ``costs`` shape (P,); returns the moved
    positions in the same row order, not clipped. A firefly is attracted only by
    strictly brighter (lower-cost) ones, so equally bright fireflies ignore each other.
    """
    order = np.argsort(costs, kind="stable")
    attractors = positions[order]
    sorted_costs = costs[order]
    moved = attractors.copy()
    for j in range(attractors.shape[0] - 1):
        first_dimmer = int(np.searchsorted(sorted_costs, sorted_costs[j], side="right"))
        if first_dimmer == attractors.shape[0]:
            break
        toward_j = attractors[j] - moved[first_dimmer:]
        squared_distance = np.einsum("pd,pd->p", toward_j, toward_j)  # eq. 2, squared
        attractiveness = beta0 * np.exp(-gamma * squared_distance)  # eq. 1
        moved[first_dimmer:] += attractiveness[:, np.newaxis] * toward_j  # eq. 3
    unsorted = np.empty_like(moved)
    unsorted[order] = moved
    return unsorted


def firefly_move(
    positions: FloatArray,
    costs: FloatArray,
    params: FireflyParameters,
    generation: int,
    rng: np.random.Generator,
) -> FloatArray:
    """One FA generation of movement: attraction, random step alpha_t eps_i, clip to [0, 1]."""
    attracted = attract_toward_brighter(positions, costs, params.beta0, params.gamma)
    random_step = random_step_scale(params, generation) * (rng.random(positions.shape) - 0.5)
    moved: FloatArray = np.clip(attracted + random_step, 0.0, 1.0)
    return moved


@dataclass(frozen=True)
class FireflyAlgorithm(ParametrisedAlgorithm):
    """Plain FA: every generation moves all fireflies (eqs. 1-4) and evaluates them."""

    params: FireflyParameters = FireflyParameters()

    name: ClassVar[str] = "fa"

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        candidates = firefly_move(
            population.positions, population.costs, self.params, generation, rng
        )
        positions, costs, _ = replace_evaluated(
            population.positions, population.costs, candidates, budget
        )
        return Population(positions, costs)


def firefly_parameters_from_settings(settings: Mapping[str, float]) -> FireflyParameters:
    """Build parameters from a Taguchi trial's settings (keys are the field names)."""
    return FireflyParameters(
        alpha0=float(settings["alpha0"]),
        beta0=float(settings["beta0"]),
        gamma=float(settings["gamma"]),
        delta=float(settings["delta"]),
        population_size=int(settings["population_size"]),
        n_generations=int(settings["n_generations"]),
    )

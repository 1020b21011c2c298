"""Baselines the paper compares the OFA with (Fig. 14): a real-coded GA and PSO.

The third baseline, plain FA, is :class:`~services.tuner.firefly.FireflyAlgorithm`. All
of them run in the same generation loop as the OFA, on [0, 1]^D, with one
batch evaluation per generation and the same budget rules, so the comparison is
at an equal number of evaluations.

* Real-coded GA: binary tournament selection, blend crossover BLX-alpha (each
  child gene uniform in [min - alpha d, max + alpha d] of the parents' genes,
  d = |difference|), Gaussian mutation per gene, clipping to [0, 1], and
  elitism (the best ``n_elite`` individuals survive unchanged and are not
  re-evaluated, so a generation costs P - n_elite evaluations).
* Global-best PSO: v <- w v + c1 u1 (personal best - x) + c2 u2 (global best - x),
  velocity clamped to +-v_max per coordinate, x <- clip(x + v, 0, 1); a
  coordinate that hits the box stops (its velocity is zeroed).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from services.tuner.evaluation import EvaluationBudget, FloatArray, IntArray
from services.tuner.generational import ParametrisedAlgorithm, Population, replace_evaluated


@dataclass(frozen=True)
class GeneticParameters:
    """Real-coded GA settings; ``mutation_probability`` None means 1/D per gene."""

    population_size: int = 40
    tournament_size: int = 2
    crossover_probability: float = 0.9
    blend_alpha: float = 0.5
    mutation_probability: float | None = None
    mutation_sigma: float = 0.1
    n_elite: int = 2
    n_generations: int | None = None

    def __post_init__(self) -> None:
        if self.population_size < 2:
            raise ValueError(f"population_size must be at least 2, got {self.population_size}")
        if not 1 <= self.tournament_size <= self.population_size:
            raise ValueError(f"tournament_size must lie in [1, P], got {self.tournament_size}")
        if not 0 <= self.n_elite < self.population_size:
            raise ValueError(f"n_elite must lie in [0, P), got {self.n_elite}")
        if not 0.0 <= self.crossover_probability <= 1.0:
            raise ValueError(
                f"crossover_probability must lie in [0, 1], got {self.crossover_probability}"
            )
        if self.mutation_probability is not None and not 0.0 <= self.mutation_probability <= 1.0:
            raise ValueError(
                f"mutation_probability must lie in [0, 1], got {self.mutation_probability}"
            )
        if self.blend_alpha < 0.0 or self.mutation_sigma < 0.0:
            raise ValueError("blend_alpha and mutation_sigma must be non-negative")


DEFAULT_GENETIC_PARAMETERS = GeneticParameters()


def tournament_select(
    costs: FloatArray, n_winners: int, tournament_size: int, rng: np.random.Generator
) -> IntArray:
    """Indices of ``n_winners`` winners, each the lowest cost among ``tournament_size`` draws."""
    contestants = rng.integers(0, costs.shape[0], size=(n_winners, tournament_size))
    winners: IntArray = contestants[np.arange(n_winners), np.argmin(costs[contestants], axis=1)]
    return winners


def blend_crossover(
    first_parents: FloatArray, second_parents: FloatArray, alpha: float, rng: np.random.Generator
) -> FloatArray:
    """BLX-alpha: each child gene uniform in its parents' interval widened by alpha each side."""
    low = np.minimum(first_parents, second_parents)
    high = np.maximum(first_parents, second_parents)
    widening = alpha * (high - low)
    children: FloatArray = (low - widening) + rng.random(low.shape) * (high - low + 2 * widening)
    return children


@dataclass(frozen=True)
class GeneticAlgorithm(ParametrisedAlgorithm):
    """Real-coded GA with elitism (see the module docstring)."""

    params: GeneticParameters = DEFAULT_GENETIC_PARAMETERS

    name: ClassVar[str] = "ga"

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        params = self.params
        n_individuals, dim = population.positions.shape
        order = np.argsort(population.costs, kind="stable")
        elites, others = order[: params.n_elite], order[params.n_elite :]
        n_children = n_individuals - elites.shape[0]

        first = tournament_select(population.costs, n_children, params.tournament_size, rng)
        second = tournament_select(population.costs, n_children, params.tournament_size, rng)
        first_parents = population.positions[first]
        crossed = blend_crossover(
            first_parents, population.positions[second], params.blend_alpha, rng
        )
        crosses = rng.random(n_children) < params.crossover_probability
        children = np.where(crosses[:, np.newaxis], crossed, first_parents)

        gene_probability = (
            1.0 / dim if params.mutation_probability is None else params.mutation_probability
        )
        mutates = rng.random(children.shape) < gene_probability
        noise = rng.normal(0.0, params.mutation_sigma, size=children.shape)
        children = np.clip(children + mutates * noise, 0.0, 1.0)

        positions, costs, _ = replace_evaluated(
            population.positions[others], population.costs[others], children, budget
        )
        return Population(
            np.concatenate([population.positions[elites], positions]),
            np.concatenate([population.costs[elites], costs]),
        )


@dataclass(frozen=True)
class ParticleSwarmParameters:
    """Global-best PSO settings; the defaults are Clerc's constriction-equivalent constants."""

    population_size: int = 40
    inertia_weight: float = 0.7298
    cognitive_coefficient: float = 1.49618
    social_coefficient: float = 1.49618
    max_velocity: float = 0.2
    n_generations: int | None = None

    def __post_init__(self) -> None:
        if self.population_size < 1:
            raise ValueError(f"population_size must be at least 1, got {self.population_size}")
        if self.max_velocity <= 0.0:
            raise ValueError(f"max_velocity must be positive, got {self.max_velocity}")


DEFAULT_PARTICLE_SWARM_PARAMETERS = ParticleSwarmParameters()


@dataclass(frozen=True)
class ParticleSwarm(ParametrisedAlgorithm):
    """Global-best PSO (see the module docstring)."""

    params: ParticleSwarmParameters = DEFAULT_PARTICLE_SWARM_PARAMETERS

    name: ClassVar[str] = "pso"

    def start(
        self, positions: FloatArray, costs: FloatArray, rng: np.random.Generator
    ) -> Population:
        v_max = self.params.max_velocity
        return Population(
            positions,
            costs,
            {
                "velocities": rng.uniform(-v_max, v_max, size=positions.shape),
                "personal_best_positions": positions.copy(),
                "personal_best_costs": costs.copy(),
            },
        )

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        params = self.params
        x = population.positions
        personal_best = population.auxiliary["personal_best_positions"]
        personal_best_costs = population.auxiliary["personal_best_costs"]
        global_best = personal_best[int(np.argmin(personal_best_costs))]

        cognitive_pull = rng.random(x.shape) * (personal_best - x)
        social_pull = rng.random(x.shape) * (global_best - x)
        velocities = np.clip(
            params.inertia_weight * population.auxiliary["velocities"]
            + params.cognitive_coefficient * cognitive_pull
            + params.social_coefficient * social_pull,
            -params.max_velocity,
            params.max_velocity,
        )
        unclipped = x + velocities
        candidates = np.clip(unclipped, 0.0, 1.0)
        velocities = np.where(candidates != unclipped, 0.0, velocities)

        positions, costs, n_evaluated = replace_evaluated(x, population.costs, candidates, budget)
        velocities[n_evaluated:] = population.auxiliary["velocities"][n_evaluated:]
        improved = costs < personal_best_costs
        return Population(
            positions,
            costs,
            {
                "velocities": velocities,
                "personal_best_positions": np.where(
                    improved[:, np.newaxis], positions, personal_best
                ),
                "personal_best_costs": np.where(improved, costs, personal_best_costs),
            },
        )

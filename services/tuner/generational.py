"""The generation loop shared by every optimiser in the tuner (OFA, FA, GA, PSO).

An algorithm only says how one generation turns the current population into the
next (eqs. 1-5 for OFA); this module owns everything the algorithms have in
common, so that they are compared on equal terms:

* the initial population is drawn uniformly in [0, 1]^D and evaluated as one batch;
* each generation evaluates its candidates as one batch through an
  :class:`~services.tuner.evaluation.EvaluationBudget`, so no run ever spends more
  than its budget (the last batch is truncated and its unevaluated candidates are
  dropped in favour of the individuals they would have replaced);
* the best candidate so far and the convergence history are recorded per generation;
* an optional progress callback is called once per generation, generation 0
  being the initial population;
* an optional checkpoint file is rewritten every ``checkpoint_every`` generations
  and at the end, and a run started with an existing checkpoint file resumes from it.
  The checkpoint records which run wrote it (algorithm, parameters, dimension,
  budget and the generator's state at the start, i.e. the seed); resuming a
  different run from it is refused with :class:`CheckpointMismatchError`.

Randomness comes only from the injected ``np.random.Generator``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from services.tuner.checkpoint import (
    CheckpointDamagedError,
    CheckpointMismatchError,
    RunCheckpoint,
    checkpoint_problem,
    json_compatible,
    load_checkpoint,
    save_checkpoint,
)
from services.tuner.evaluation import EvaluationBudget, FloatArray, Objective, ProgressCallback
from services.tuner.result import ConvergenceHistory, OptimisationResult


@dataclass(frozen=True)
class Population:
    """Candidates in [0, 1]^D, shape (P, D), their costs, shape (P,), and per-algorithm arrays."""

    positions: FloatArray
    costs: FloatArray
    auxiliary: Mapping[str, FloatArray] = field(default_factory=dict)


class PopulationAlgorithm(Protocol):
    """One population-based optimiser, seen by the generation loop."""

    @property
    def name(self) -> str:
        """Short algorithm name, stored in results and checkpoints."""
        ...

    @property
    def population_size(self) -> int:
        """Number of individuals P."""
        ...

    @property
    def max_generations(self) -> int | None:
        """Generations after the initial population (N_fa), or None to run until the budget ends."""
        ...

    def settings(self) -> Mapping[str, object]:
        """JSON-serialisable parameters, stored in the checkpoint fingerprint."""
        ...

    def start(
        self, positions: FloatArray, costs: FloatArray, rng: np.random.Generator
    ) -> Population:
        """Build the initial population state from the evaluated initial candidates."""
        ...

    def step(
        self,
        population: Population,
        generation: int,
        rng: np.random.Generator,
        budget: EvaluationBudget,
    ) -> Population:
        """Produce generation ``generation + 1`` from ``population``, evaluating one batch."""
        ...


class AlgorithmParameters(Protocol):
    """What the generation loop reads from an algorithm's parameter dataclass."""

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def population_size(self) -> int: ...

    @property
    def n_generations(self) -> int | None: ...


class ParametrisedAlgorithm:
    """The parts of :class:`PopulationAlgorithm` that follow from one frozen parameter
    dataclass ``params``: P, the generation limit, the checkpoint settings, and an initial
    population state of positions and costs alone (PSO overrides :meth:`start`)."""

    params: AlgorithmParameters

    @property
    def population_size(self) -> int:
        return self.params.population_size

    @property
    def max_generations(self) -> int | None:
        return self.params.n_generations

    def settings(self) -> Mapping[str, object]:
        return asdict(self.params)

    def start(
        self, positions: FloatArray, costs: FloatArray, rng: np.random.Generator
    ) -> Population:
        return Population(positions, costs)


def replace_evaluated(
    previous_positions: FloatArray,
    previous_costs: FloatArray,
    candidates: FloatArray,
    budget: EvaluationBudget,
) -> tuple[FloatArray, FloatArray, int]:
    """Evaluate ``candidates`` in one batch and let each evaluated row replace its predecessor.

    Rows the budget could not pay for keep the previous position and cost.
    Returns (positions, costs, number of rows evaluated).
    """
    new_costs = budget.evaluate(candidates)
    n_evaluated = new_costs.shape[0]
    positions = previous_positions.copy()
    costs = previous_costs.copy()
    positions[:n_evaluated] = candidates[:n_evaluated]
    costs[:n_evaluated] = new_costs
    return positions, costs, n_evaluated


def _fingerprint(
    algorithm: PopulationAlgorithm, dim: int, budget: int, rng: np.random.Generator
) -> str:
    """Identifies a run: algorithm, parameters, dimension, budget, generator start state."""
    return json.dumps(
        {
            "algorithm": algorithm.name,
            "dim": dim,
            "budget": budget,
            "initial_rng_state": rng.bit_generator.state,
            "population_size": algorithm.population_size,
            "max_generations": algorithm.max_generations,
            "settings": dict(algorithm.settings()),
        },
        sort_keys=True,
        default=json_compatible,
    )


@dataclass
class _RunState:
    generation: int
    population: Population
    best_x: FloatArray
    best_cost: float
    history_n_evaluations: list[int]
    history_best_cost: list[float]

    def record(self, population: Population, n_evaluations: int) -> None:
        self.population = population
        if population.costs.size > 0:
            index = int(np.argmin(population.costs))
            if population.costs[index] < self.best_cost:
                self.best_cost = float(population.costs[index])
                self.best_x = population.positions[index].copy()
        self.history_n_evaluations.append(n_evaluations)
        self.history_best_cost.append(self.best_cost)


@dataclass
class _Checkpointer:
    """Writes the run state to ``path`` every ``every`` generations, once per generation."""

    path: Path | None
    fingerprint: str
    every: int
    saved_generation: int | None = None

    def save(self, state: _RunState, n_evaluations: int, rng: np.random.Generator) -> None:
        if self.path is None or self.saved_generation == state.generation:
            return
        checkpoint = RunCheckpoint(
            fingerprint=self.fingerprint,
            generation=state.generation,
            positions=state.population.positions,
            costs=state.population.costs,
            best_x=state.best_x,
            best_cost=state.best_cost,
            n_evaluations=n_evaluations,
            history_n_evaluations=np.array(state.history_n_evaluations, dtype=np.int64),
            history_best_cost=np.array(state.history_best_cost, dtype=np.float64),
            rng_state=rng.bit_generator.state,
            auxiliary=dict(state.population.auxiliary),
        )
        save_checkpoint(self.path, checkpoint)
        self.saved_generation = state.generation

    def save_if_due(self, state: _RunState, n_evaluations: int, rng: np.random.Generator) -> None:
        if state.generation % self.every == 0:
            self.save(state, n_evaluations, rng)


def _resume(
    checkpoint_path: Path, fingerprint: str, dim: int, budget: int, rng: np.random.Generator
) -> tuple[_RunState, int]:
    checkpoint = load_checkpoint(checkpoint_path)
    if checkpoint.fingerprint != fingerprint:
        raise CheckpointMismatchError(
            f"checkpoint {checkpoint_path} belongs to a different run: "
            f"{checkpoint.fingerprint} != {fingerprint}"
        )
    problem = checkpoint_problem(checkpoint, dim, budget)
    try:
        if problem is None:
            rng.bit_generator.state = dict(checkpoint.rng_state)
    except (TypeError, ValueError, KeyError, OverflowError) as exc:  # numpy refuses the state
        problem = f"rng_state: {type(exc).__name__}"
    if problem is not None:
        raise CheckpointDamagedError.at(checkpoint_path, problem)
    progress = _RunState(
        generation=checkpoint.generation,
        population=Population(checkpoint.positions, checkpoint.costs, checkpoint.auxiliary),
        best_x=checkpoint.best_x,
        best_cost=checkpoint.best_cost,
        history_n_evaluations=[int(n) for n in checkpoint.history_n_evaluations],
        history_best_cost=[float(c) for c in checkpoint.history_best_cost],
    )
    return progress, checkpoint.n_evaluations


def run_population_algorithm(
    algorithm: PopulationAlgorithm,
    objective: Objective,
    dim: int,
    budget: int,
    rng: np.random.Generator,
    *,
    checkpoint_path: str | os.PathLike[str] | None = None,
    checkpoint_every: int = 10,
    progress: ProgressCallback | None = None,
) -> OptimisationResult:
    """Minimise ``objective`` over [0, 1]^dim with at most ``budget`` evaluations.

    The run stops when the budget is spent or after ``algorithm.max_generations``
    generations, whichever comes first. With ``checkpoint_path`` set, the state is
    saved every ``checkpoint_every`` generations and when the run ends; if the file
    already exists, the run resumes from it (``rng`` must be in the state the
    interrupted run started from, e.g. freshly seeded with the same seed, and is
    moved to the saved state), giving the same result as an uninterrupted run.
    """
    if dim < 1:
        raise ValueError(f"dim must be at least 1, got {dim}")
    if checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be at least 1, got {checkpoint_every}")
    path = None if checkpoint_path is None else Path(checkpoint_path)
    checkpointer = _Checkpointer(path, _fingerprint(algorithm, dim, budget, rng), checkpoint_every)

    def finish_generation(state: _RunState, evaluations: EvaluationBudget) -> None:
        checkpointer.save_if_due(state, evaluations.n_evaluations, rng)
        if progress is not None:
            progress(state.generation, evaluations.n_evaluations, state.best_cost)

    if path is not None and path.exists():
        state, n_evaluations = _resume(path, checkpointer.fingerprint, dim, budget, rng)
        checkpointer.saved_generation = state.generation
        evaluations = EvaluationBudget(objective, budget, n_evaluations)
    else:
        evaluations = EvaluationBudget(objective, budget)
        initial = rng.random((algorithm.population_size, dim))
        initial_costs = evaluations.evaluate(initial)
        population = algorithm.start(initial[: initial_costs.shape[0]], initial_costs, rng)
        state = _RunState(
            generation=0,
            population=population,
            best_x=np.full(dim, np.nan),
            best_cost=float("inf"),
            history_n_evaluations=[],
            history_best_cost=[],
        )
        state.record(population, evaluations.n_evaluations)
        finish_generation(state, evaluations)

    limit = algorithm.max_generations
    while not evaluations.exhausted and (limit is None or state.generation < limit):
        next_population = algorithm.step(state.population, state.generation, rng, evaluations)
        state.generation += 1
        state.record(next_population, evaluations.n_evaluations)
        finish_generation(state, evaluations)
    checkpointer.save(state, evaluations.n_evaluations, rng)

    return OptimisationResult(
        algorithm=algorithm.name,
        best_x=state.best_x.copy(),
        best_cost=state.best_cost,
        n_evaluations=evaluations.n_evaluations,
        n_generations=state.generation,
        history=ConvergenceHistory(
            n_evaluations=np.array(state.history_n_evaluations, dtype=np.int64),
            best_cost=np.array(state.history_best_cost, dtype=np.float64),
        ),
    )

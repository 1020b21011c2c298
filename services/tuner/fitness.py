"""Fitness of candidate fuzzy schedulers on a scenario: eq. 16 through the batch simulator.

A batch of decision vectors (P, 16) (:mod:`services.tuner.fuzzy_encoding`) is decoded into P
schedulers and simulated in ONE :func:`~services.sim.batch.run_batch` call with shared noise:
every candidate meets the same sensor noise, wheel slip and radio losses (common random
numbers), so their costs differ by the scheduler alone. A candidate's cost does not depend on
which other candidates share its batch, and the same seed gives the same costs, so the objective
is a deterministic function of the vector.

Cost, to be minimised (the optimisers' contract), is the argument of the logarithm in eq. 16:

    cost = w_e · mean_t Σ_i (|x_ei| + |y_ei| + |θ_ei|) + w_r · Σ_i N_i  [+ collision penalty]

The error term is the time average over the fitness window of the sum over robots of the
absolute pose errors (m and rad added as numbers, DESIGN §6 and §8, errors from ground truth).
The window is the scenario's ``metrics.fitness_window_start_s`` (default 0: the whole run,
the transient from the starting poses included, which is where gain scheduling matters most);
the tracking RMS figures keep their own steady-state window. Σ_i N_i is the rule count
K = n_e · n_ė of the candidate times the number of robots, since every robot runs the same
scheduler. The weights are the scenario's ``fitness`` section.
The fitness is eq. 16, fitness_db = -10 log10(cost), maximised.

Collisions: the metrics count contact onsets (robot-robot and robot-obstacle). A candidate
that collides gets ``collision_penalty`` (default 1.0, in the units of the error term) added to
its cost per collision, so that one collision weighs as much as a metre of average absolute
error: far more than the cost of any collision-free candidate of the paper scenario (random
candidates cost 0.15-0.17 at 30 s evaluations), while colliding candidates stay ordered by their
tracking error. A candidate whose error sum is not finite costs :data:`FAILED_CANDIDATE_COST`.

Shorter evaluations: ``duration_s`` shortens the simulated run (tuning is dominated by
simulation time). Both windows then keep their share of the run: a start becomes
start · duration_s / scenario.duration_s (20 s of 60 s becomes 10 s of 30 s; the default
fitness window, from 0 s, stays the whole run). :func:`evaluation_scenario` builds that
scenario; its metrics are what the fitness uses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from services.sim.batch import run_batch
from services.tuner.evaluation import FloatArray, IntArray, Objective, snr_fitness_from_cost
from services.tuner.fuzzy_encoding import decode
from swarm_config.scenario import MAX_TICKS, FitnessSpec, Scenario
from world.metrics import FormationLayout

DEFAULT_COLLISION_PENALTY = 1.0
"""Cost added per collision, in the units of the eq. 16 error term."""
FAILED_CANDIDATE_COST = 1.0e3
"""Cost of a candidate whose simulated error is not finite."""


@dataclass(frozen=True)
class FitnessResult:
    """Per-candidate outcome of :func:`evaluate_fitness`; every array has leading length P.

    cost: what the optimisers minimise (eq. 16's argument plus collision penalties);
    fitness_db: -10 log10(cost), eq. 16 (exactly eq. 16 for a collision-free candidate);
    mean_abs_error_sum: time-averaged Σ_i (|x_e| + |y_e| + |θ_e|) over the fitness window;
    rule_count: Σ_i N_i, the rules of all robots;
    collisions: contact onsets during the run;
    leader_tracking_rms_m: leader position RMS over nominal steady-state samples (NaN if none);
    formation_rms_m: (P, F) follower position RMS, columns in ``follower_names`` order;
    fitness_window_start_s, steady_state_start_s: window starts of the evaluated (possibly
    shortened) runs, for the error term and for the RMS figures.
    """

    cost: FloatArray
    fitness_db: FloatArray
    mean_abs_error_sum: FloatArray
    rule_count: IntArray
    collisions: IntArray
    leader_tracking_rms_m: FloatArray
    formation_rms_m: FloatArray
    follower_names: tuple[str, ...]
    duration_s: float
    fitness_window_start_s: float
    steady_state_start_s: float
    seed: int


def eq16_cost(
    mean_abs_error_sum: ArrayLike,
    rule_count: ArrayLike,
    collisions: ArrayLike,
    weights: FitnessSpec,
    collision_penalty: float = DEFAULT_COLLISION_PENALTY,
) -> FloatArray:
    """The argument of eq. 16's logarithm, per candidate, plus the collision penalty.

    w_e · mean_t Σ_i (|x_ei| + |y_ei| + |θ_ei|) + w_r · Σ_i N_i + penalty · collisions; a
    candidate whose cost is not finite and positive costs :data:`FAILED_CANDIDATE_COST`.
    """
    cost = (
        weights.error_weight * np.asarray(mean_abs_error_sum, dtype=np.float64)
        + weights.rule_weight * np.asarray(rule_count, dtype=np.float64)
        + collision_penalty * np.asarray(collisions, dtype=np.float64)
    )
    checked: FloatArray = np.where(np.isfinite(cost) & (cost > 0.0), cost, FAILED_CANDIDATE_COST)
    return checked


def evaluation_duration_problem(scenario: Scenario, duration_s: float) -> str | None:
    """Why ``duration_s`` cannot be the simulated seconds of one evaluation of ``scenario``,
    else None: not a positive number, shorter than two control periods, or over the scenario's
    own tick limit (`MAX_TICKS` control periods, as `swarm sim --duration`; before, `swarm
    tune --duration 1e9` was accepted and computed without end)."""
    if not np.isfinite(duration_s) or duration_s <= 0.0:
        return f"evaluation duration must be a positive number of seconds, got {duration_s}"
    period_s = scenario.controller.control_period_s
    if duration_s < 2.0 * period_s:
        return f"evaluation duration {duration_s} s is shorter than two control periods"
    if duration_s / period_s > MAX_TICKS:
        return (
            f"evaluation duration {duration_s:g} s is over ten million control periods of "
            f"{period_s:g} s (at most {MAX_TICKS * period_s:g} s)"
        )
    return None


def evaluation_scenario(scenario: Scenario, duration_s: float | None = None) -> Scenario:
    """The scenario a candidate is scored on: shortened to ``duration_s``, windows rescaled.

    The fuzzy scheduler is always enabled (it is what is being scored). Raises ValueError when
    the duration is not one an evaluation can last (`evaluation_duration_problem`) or the
    fitness window would hold no sample.
    """
    duration = scenario.duration_s if duration_s is None else float(duration_s)
    problem = evaluation_duration_problem(scenario, duration)
    if problem is not None:
        raise ValueError(problem)
    share = duration / scenario.duration_s
    fitness_start = scenario.metrics.fitness_window_start_s * share
    if fitness_start >= duration:
        raise ValueError(
            f"scenario {scenario.name!r}: the fitness window starts at "
            f"{scenario.metrics.fitness_window_start_s} s, not before the end of the run "
            f"({scenario.duration_s} s), so eq. 16 has no samples"
        )
    controller = scenario.controller.model_copy(update={"fuzzy_enabled": True})
    metrics = scenario.metrics.model_copy(
        update={
            "steady_state_start_s": scenario.metrics.steady_state_start_s * share,
            "fitness_window_start_s": fitness_start,
        }
    )
    return scenario.model_copy(
        update={"duration_s": duration, "metrics": metrics, "controller": controller}
    )


def _summary_figure(value: object) -> float:
    """A summary number as float; None (no samples) becomes NaN."""
    if value is None:
        return float("nan")
    if not isinstance(value, int | float):
        raise TypeError(f"expected a number in the run summary, got {value!r}")
    return float(value)


def _formation_rms(summary: dict[str, object], follower_names: tuple[str, ...]) -> list[float]:
    per_follower = summary["formation_rms_m"]
    if not isinstance(per_follower, dict):
        raise TypeError("formation_rms_m of a run summary must map follower names to figures")
    return [_summary_figure(per_follower.get(name)) for name in follower_names]


def evaluate_fitness(
    unit_vectors: ArrayLike,
    scenario: Scenario,
    *,
    duration_s: float | None = None,
    seed: int | None = None,
    collision_penalty: float = DEFAULT_COLLISION_PENALTY,
) -> FitnessResult:
    """Score a batch of decision vectors (P, 16) in [0, 1] on ``scenario`` (eq. 16).

    One batch simulation of P runs with shared noise (common random numbers); ``seed``
    defaults to the scenario's, ``duration_s`` to its duration (the windows are rescaled,
    see the module docstring). Returns costs for minimisation and the figures behind them.
    """
    if collision_penalty < 0.0:
        raise ValueError(f"collision_penalty must be non-negative, got {collision_penalty}")
    rule_base = decode(unit_vectors)
    batch_size = int(rule_base.error_set_count.shape[0])
    evaluated = evaluation_scenario(scenario, duration_s)
    noise_seed = evaluated.seed if seed is None else int(seed)
    result = run_batch(
        evaluated,
        batch_size=batch_size,
        rule_base=rule_base,
        controller=evaluated.controller_params(),
        shared_noise=True,
        seed=noise_seed,
    )
    error_sum = np.asarray(result.metrics.mean_abs_error_sum(), dtype=np.float64).reshape(-1)
    rule_count = np.asarray(result.rule_count, dtype=np.int64).reshape(-1)
    collisions = np.asarray(result.metrics.collisions, dtype=np.int64).reshape(-1)
    cost = eq16_cost(error_sum, rule_count, collisions, evaluated.fitness, collision_penalty)
    layout = FormationLayout.from_scenario(evaluated)
    follower_names = tuple(layout.names[i] for i in layout.follower_indices)
    formation = np.array(
        [_formation_rms(s, follower_names) for s in result.summaries], dtype=np.float64
    ).reshape(batch_size, len(follower_names))
    return FitnessResult(
        cost=cost,
        fitness_db=snr_fitness_from_cost(cost),
        mean_abs_error_sum=error_sum,
        rule_count=rule_count,
        collisions=collisions,
        leader_tracking_rms_m=np.array(
            [_summary_figure(s["leader_tracking_rms_m"]) for s in result.summaries]
        ),
        formation_rms_m=formation,
        follower_names=follower_names,
        duration_s=evaluated.duration_s,
        fitness_window_start_s=evaluated.metrics.fitness_window_start_s,
        steady_state_start_s=evaluated.metrics.steady_state_start_s,
        seed=noise_seed,
    )


FitnessObserver = Callable[[FloatArray, FitnessResult], None]
"""Called after every evaluated batch with the vectors and their :class:`FitnessResult`."""


def make_objective(
    scenario: Scenario,
    *,
    duration_s: float | None = None,
    seed: int | None = None,
    collision_penalty: float = DEFAULT_COLLISION_PENALTY,
    observer: FitnessObserver | None = None,
) -> Objective:
    """The optimisers' objective: decision vectors (P, 16) to costs (P,), one simulation each call.

    Arguments as for :func:`evaluate_fitness`; they are checked here, so a bad duration fails
    before any optimiser starts. ``observer`` sees every batch (for logs or archives).
    """
    evaluation_scenario(scenario, duration_s)
    if collision_penalty < 0.0:
        raise ValueError(f"collision_penalty must be non-negative, got {collision_penalty}")

    def objective(unit_vectors: FloatArray) -> FloatArray:
        result = evaluate_fitness(
            unit_vectors,
            scenario,
            duration_s=duration_s,
            seed=seed,
            collision_penalty=collision_penalty,
        )
        if observer is not None:
            observer(unit_vectors, result)
        return result.cost

    return objective

"""Eq. 16 fitness of candidate schedulers through one shared-noise batch simulation."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.sim.batch import run_batch
from services.tuner.evaluation import snr_fitness_from_cost
from services.tuner.fitness import (
    eq16_cost,
    evaluate_fitness,
    evaluation_scenario,
    make_objective,
)
from services.tuner.fuzzy_encoding import DIMENSION, encode_default
from swarm_config.metrics import MetricsConfig
from swarm_config.scenario import FitnessSpec, Scenario, load_scenario, parse_scenario
from world.metrics import FormationLayout, MetricsAccumulator, fitness_snr
from world.summary import build_summary

ROOT = Path(__file__).resolve().parents[3]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
SHORT_S = 2.0


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return load_scenario(PAPER)


@pytest.fixture(scope="module")
def candidates() -> np.ndarray:
    rng = np.random.default_rng(11)
    return np.vstack([encode_default(), rng.random((3, DIMENSION))])


def test_table2_vector_scores_what_run_batch_gives_directly(paper: Scenario) -> None:
    result = evaluate_fitness(encode_default(), paper, duration_s=SHORT_S)
    scored = evaluation_scenario(paper, SHORT_S)
    direct = run_batch(
        scored, batch_size=1, rule_base=FuzzyRuleBase.table2(), shared_noise=True, seed=paper.seed
    )
    error_sum = direct.metrics.mean_abs_error_sum()
    expected_db = fitness_snr(
        error_sum,
        direct.rule_count.astype(np.float64),
        paper.fitness.error_weight,
        paper.fitness.rule_weight,
    )
    np.testing.assert_allclose(result.fitness_db, expected_db, rtol=1e-12)
    np.testing.assert_array_equal(result.mean_abs_error_sum, error_sum)
    np.testing.assert_array_equal(result.rule_count, [49 * len(paper.robots)])
    assert result.collisions.tolist() == [0]
    assert result.leader_tracking_rms_m[0] == direct.summaries[0]["leader_tracking_rms_m"]
    assert result.follower_names == ("robot2", "robot3")
    assert result.formation_rms_m.shape == (1, 2)


def test_batch_is_deterministic_and_candidates_do_not_affect_each_other(
    paper: Scenario, candidates: np.ndarray
) -> None:
    together = evaluate_fitness(candidates, paper, duration_s=SHORT_S)
    again = evaluate_fitness(candidates, paper, duration_s=SHORT_S)
    np.testing.assert_array_equal(together.cost, again.cost)
    assert len(set(together.cost.tolist())) == len(candidates)  # the candidates differ
    reversed_order = evaluate_fitness(candidates[::-1], paper, duration_s=SHORT_S)
    np.testing.assert_array_equal(reversed_order.cost[::-1], together.cost)
    for index in (0, 2):
        alone = evaluate_fitness(candidates[index], paper, duration_s=SHORT_S)
        assert alone.cost[0] == together.cost[index]


def test_another_noise_seed_gives_other_costs(paper: Scenario) -> None:
    first = evaluate_fitness(encode_default(), paper, duration_s=SHORT_S, seed=1)
    second = evaluate_fitness(encode_default(), paper, duration_s=SHORT_S, seed=2)
    assert first.cost[0] != second.cost[0]
    assert first.seed == 1


# Two robots, the follower's slot 1 m straight behind the leader. After the transient every
# sample has the same, known errors; before it, the leader is 0.4 m further off in x.
HAND_LAYOUT = FormationLayout(
    names=("robot1", "robot2"),
    leader_index=0,
    slot_distance_m=np.array([0.0, 1.0]),
    slot_angle_rad=np.array([0.0, np.pi]),
)
HAND_REFERENCE = np.array([0.0, 0.0, 0.05])  # the leader's trajectory pose, θ_d = 0.05 rad
SETTLED_POSE = np.array(
    [
        [0.03, -0.04, 0.0],  # leader: x_e = 0.03, y_e = -0.04, θ_e = -0.05 -> 0.12
        [0.03 - 1.0 + 0.01, -0.04 + 0.02, -0.03],  # follower vs slot (-0.97, -0.04, 0): 0.06
    ]
)
TRANSIENT_POSE = SETTLED_POSE + np.array([[0.4, 0.0, 0.0], [0.4, 0.0, 0.0]])  # leader: 0.52
# Samples every 0.1 s for 2 s: t < 0.5 s (5 samples) transient, Σ|e| = 0.52 + 0.06 = 0.58;
# t >= 0.5 s (15 samples) settled, Σ|e| = 0.12 + 0.06 = 0.18. Over the whole run the mean is
# (5 · 0.58 + 15 · 0.18) / 20 = 0.28; from 0.45 s on it is 0.18.


def _hand_metrics(fitness_window_start_s: float) -> MetricsAccumulator:
    config = MetricsConfig(
        steady_state_start_s=1.0,
        fitness_window_start_s=fitness_window_start_s,
        nominal_hold_s=0.5,
        apf_influence_m=0.4,
        body_radius_m=0.3,
    )
    metrics = MetricsAccumulator((1,), HAND_LAYOUT, np.zeros((0, 2)), np.zeros(0), config)
    for k in range(20):
        pose = TRANSIENT_POSE if k < 5 else SETTLED_POSE
        metrics.update(0.1 * k, pose[None], HAND_REFERENCE)
    return metrics


@pytest.mark.parametrize(
    ("window_start_s", "error_weight", "rule_weight", "expected_db"),
    [
        # K = 3 x 5 = 15 rules on each of the two robots: Σ_i N_i = 30.
        (0.0, 1.0, 1e-4, -10.0 * math.log10(1.0 * 0.28 + 1e-4 * 30)),  # 5.482 dB
        (0.45, 1.0, 1e-4, -10.0 * math.log10(1.0 * 0.18 + 1e-4 * 30)),  # 7.375 dB
        (0.0, 2.0, 1e-3, -10.0 * math.log10(2.0 * 0.28 + 1e-3 * 30)),  # 2.291 dB
    ],
)
def test_eq16_of_a_hand_computed_error_sequence(
    window_start_s: float, error_weight: float, rule_weight: float, expected_db: float
) -> None:
    metrics = _hand_metrics(window_start_s)
    weights = FitnessSpec(error_weight=error_weight, rule_weight=rule_weight)
    cost = eq16_cost(metrics.mean_abs_error_sum(), [30], metrics.collisions, weights)
    assert metrics.collisions.tolist() == [0]
    assert snr_fitness_from_cost(cost)[0] == pytest.approx(expected_db, abs=1e-9)
    # summary.json reports the same eq. 16 from the same samples.
    scenario = load_scenario(PAPER).model_copy(update={"fitness": weights})
    summary = build_summary(scenario, metrics.summaries()[0], True, 30, 0, 0)
    assert summary["fitness_snr_db"] == pytest.approx(expected_db, abs=1e-5)


def test_rule_counts_of_decoded_candidates_enter_the_cost(paper: Scenario) -> None:
    result = evaluate_fitness(
        np.vstack([encode_default(7, 7), encode_default(3, 3)]), paper, duration_s=SHORT_S
    )
    np.testing.assert_array_equal(result.rule_count, [3 * 49, 3 * 9])
    # Same error sum up to the scheduler's effect; 120 more rules cost 120 · w_r more.
    rules_cost = paper.fitness.rule_weight * (147 - 27)
    error_cost = paper.fitness.error_weight * np.diff(result.mean_abs_error_sum[::-1])[0]
    assert result.cost[0] - result.cost[1] == pytest.approx(rules_cost + error_cost, rel=1e-12)


def test_a_colliding_candidate_pays_the_penalty_per_collision() -> None:
    data = yaml.safe_load(PAPER.read_text(encoding="utf-8"))
    data["controller"] = {"apf_robot_gain": 0.0, "apf_obstacle_gain": 0.0, "approach_guard": False}
    data["obstacles"] = [{"position_m": [1.147, 0.966], "radius_m": 0.15}]  # on the leader's path
    blind = parse_scenario(data)
    free = evaluate_fitness(encode_default(), blind, duration_s=SHORT_S, collision_penalty=0.0)
    penalised = evaluate_fitness(encode_default(), blind, duration_s=SHORT_S)
    assert penalised.collisions[0] >= 1
    assert penalised.cost[0] == pytest.approx(free.cost[0] + 1.0 * penalised.collisions[0])
    assert penalised.fitness_db[0] < free.fitness_db[0]


def test_shorter_evaluations_keep_the_windows_share(paper: Scenario) -> None:
    assert paper.metrics.fitness_window_start_s == 0.0  # eq. 16 averages over the whole run
    shortened = evaluation_scenario(paper, 30.0)
    assert shortened.duration_s == 30.0
    assert shortened.metrics.steady_state_start_s == pytest.approx(
        paper.metrics.steady_state_start_s / 2.0
    )
    assert shortened.metrics.fitness_window_start_s == 0.0
    late = paper.model_copy(
        update={"metrics": paper.metrics.model_copy(update={"fitness_window_start_s": 12.0})}
    )
    assert evaluation_scenario(late, 30.0).metrics.fitness_window_start_s == pytest.approx(6.0)
    assert evaluation_scenario(paper).duration_s == paper.duration_s


def test_the_fitness_window_decides_which_samples_eq16_averages(paper: Scenario) -> None:
    late = paper.model_copy(
        update={"metrics": paper.metrics.model_copy(update={"fitness_window_start_s": 1.0})}
    )
    whole = evaluate_fitness(encode_default(), paper, duration_s=SHORT_S)
    settled = evaluate_fitness(encode_default(), late, duration_s=SHORT_S)
    assert whole.fitness_window_start_s == 0.0 and settled.fitness_window_start_s == 1.0 / 30.0
    assert whole.mean_abs_error_sum[0] != settled.mean_abs_error_sum[0]
    # The tracking figures keep the steady-state window: the same for both.
    assert whole.leader_tracking_rms_m[0] == settled.leader_tracking_rms_m[0] or (
        np.isnan(whole.leader_tracking_rms_m[0]) and np.isnan(settled.leader_tracking_rms_m[0])
    )


def test_a_fitness_window_past_the_run_is_refused(paper: Scenario) -> None:
    late = paper.model_copy(
        update={"metrics": paper.metrics.model_copy(update={"fitness_window_start_s": 60.0})}
    )
    with pytest.raises(ValueError, match="fitness window"):
        make_objective(late, duration_s=30.0)


@pytest.mark.parametrize("duration_s", [0.0, -5.0, float("nan"), 0.005])
def test_bad_durations_are_refused_before_any_simulation(
    paper: Scenario, duration_s: float
) -> None:
    with pytest.raises(ValueError, match="duration"):
        make_objective(paper, duration_s=duration_s)


def test_objective_returns_the_costs_and_shows_every_batch(
    paper: Scenario, candidates: np.ndarray
) -> None:
    seen: list[int] = []
    objective = make_objective(
        paper, duration_s=SHORT_S, observer=lambda x, result: seen.append(x.shape[0])
    )
    costs = objective(candidates[:2])
    expected = evaluate_fitness(candidates[:2], paper, duration_s=SHORT_S).cost
    np.testing.assert_array_equal(costs, expected)
    assert seen == [2]
    assert np.all(costs > 0.0)

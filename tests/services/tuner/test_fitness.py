"""Eq. 16 fitness of candidate schedulers through one shared-noise batch simulation."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.sim.batch import run_batch
from services.tuner.fitness import (
    evaluate_fitness,
    evaluation_scenario,
    make_objective,
)
from services.tuner.fuzzy_encoding import DIMENSION, encode_default
from swarm_config.scenario import Scenario, load_scenario, parse_scenario
from world.metrics import fitness_snr

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


def test_rule_count_enters_the_cost_with_the_rule_weight(paper: Scenario) -> None:
    result = evaluate_fitness(
        np.vstack([encode_default(7, 7), encode_default(3, 3)]), paper, duration_s=SHORT_S
    )
    np.testing.assert_array_equal(result.rule_count, [147, 27])
    weights = paper.fitness
    np.testing.assert_allclose(
        result.cost,
        weights.error_weight * result.mean_abs_error_sum + weights.rule_weight * result.rule_count,
        rtol=1e-15,
    )


def test_a_colliding_candidate_pays_the_penalty_per_collision() -> None:
    data = yaml.safe_load(PAPER.read_text(encoding="utf-8"))
    data["controller"] = {"apf_robot_gain": 0.0, "apf_obstacle_gain": 0.0}
    data["obstacles"] = [{"position_m": [1.147, 0.966], "radius_m": 0.15}]  # on the leader's path
    blind = parse_scenario(data)
    free = evaluate_fitness(encode_default(), blind, duration_s=SHORT_S, collision_penalty=0.0)
    penalised = evaluate_fitness(encode_default(), blind, duration_s=SHORT_S)
    assert penalised.collisions[0] >= 1
    assert penalised.cost[0] == pytest.approx(free.cost[0] + 1.0 * penalised.collisions[0])
    assert penalised.fitness_db[0] < free.fitness_db[0]


def test_shorter_evaluations_keep_the_steady_window_share(paper: Scenario) -> None:
    shortened = evaluation_scenario(paper, 30.0)
    assert shortened.duration_s == 30.0
    assert shortened.metrics.steady_state_start_s == pytest.approx(
        paper.metrics.steady_state_start_s / 2.0
    )
    assert evaluation_scenario(paper).duration_s == paper.duration_s


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

"""Generated formations: valid scenarios, collision-free at rest, reproducible."""

import math
import re

import numpy as np
import pytest
import yaml

from robot_firmware.control.apf import repulsive_force
from robot_firmware.control.formation import follower_slot_in_world
from swarm_config.generate import (
    FORMATIONS,
    MAX_ROBOTS,
    START_MARGIN_M,
    TRAJECTORIES,
    GenerateRequest,
    ScenarioGenerationError,
    generate_scenario_text,
)
from swarm_config.scenario import Scenario, parse_scenario

# The rule the generator promises: at their slots, robots' bodies are at least the APF influence
# distance apart (eq. 25 is zero there), so every follower can reach its slot and stay.
SLOT_MARGIN_M = 0.0


def _generate(**fields: object) -> tuple[str, Scenario]:
    text = generate_scenario_text(GenerateRequest(**fields))  # type: ignore[arg-type]
    return text, parse_scenario(yaml.safe_load(text), "generated")


def _slots_at_start(scenario: Scenario) -> np.ndarray:
    """Each robot's reference at t = 0, from the file alone: leader on the path, slots by eq. 17."""
    leader, _ = scenario.trajectory.build().evaluate(0.0)
    points = []
    for robot in scenario.robots:
        if robot.slot is None:
            points.append(np.asarray(leader[:2]))
        else:
            points.append(
                follower_slot_in_world(
                    leader, robot.slot.distance_m, math.radians(robot.slot.angle_deg)
                )
            )
    return np.array(points)


def _pair_distances(points: np.ndarray) -> np.ndarray:
    i, j = np.triu_indices(len(points), k=1)
    return np.hypot(*(points[i] - points[j]).T)


def _check_at_rest(scenario: Scenario, robots: int) -> None:
    body_m = scenario.robot_body.body_radius_m
    influence_m = scenario.controller_params().apf_influence_m
    assert len(scenario.robots) == robots
    assert [r.role for r in scenario.robots].count("leader") == 1
    slots = _slots_at_start(scenario)
    starts = scenario.initial_poses()[:, :2]
    if robots > 1:
        assert _pair_distances(slots).min() >= 2 * body_m + influence_m + SLOT_MARGIN_M - 1e-9
        assert _pair_distances(starts).min() >= 2 * body_m + START_MARGIN_M - 1e-9
    for obstacle in scenario.obstacles:
        centre = np.asarray(obstacle.position_m)
        assert np.hypot(*(slots - centre).T).min() >= obstacle.radius_m + body_m + influence_m
        assert np.hypot(*(starts - centre).T).min() >= obstacle.radius_m + body_m


@pytest.mark.parametrize("formation", FORMATIONS)
def test_every_size_validates_and_keeps_slots_and_starts_apart(formation: str) -> None:
    for robots in range(1, 65):
        _, scenario = _generate(robots=robots, formation=formation)
        _check_at_rest(scenario, robots)


@pytest.mark.parametrize("formation", FORMATIONS)
def test_the_largest_swarm_allowed_can_be_generated(formation: str) -> None:
    """Up to `MAX_ROBOTS`: the generator's own placeholder starts once lay beyond the
    positioning receiver's range from the 216th robot on, so 216-256 robots were refused."""
    for robots in (215, 216, MAX_ROBOTS):
        _, scenario = _generate(robots=robots, formation=formation, obstacles=3)
        _check_at_rest(scenario, robots)


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
@pytest.mark.parametrize("formation", FORMATIONS)
@pytest.mark.parametrize("robots", [1, 2, 5, 24, 64])
def test_every_path_validates_and_keeps_slots_apart(
    trajectory: str, formation: str, robots: int
) -> None:
    _, scenario = _generate(robots=robots, formation=formation, trajectory=trajectory)
    assert scenario.trajectory.kind == trajectory
    _check_at_rest(scenario, robots)


@pytest.mark.parametrize("formation", FORMATIONS)
def test_robots_at_their_slots_do_not_repel_each_other(formation: str) -> None:
    _, scenario = _generate(robots=36, formation=formation)
    params = scenario.controller_params()
    slots = _slots_at_start(scenario)
    offsets = slots[:, None, :] - slots[None, :, :]
    centre_m = np.hypot(offsets[..., 0], offsets[..., 1])
    others = ~np.eye(len(slots), dtype=bool)
    direction = offsets / np.where(others, centre_m, 1.0)[..., None]
    force = repulsive_force(
        direction,
        centre_m - 2 * scenario.robot_body.body_radius_m,
        others,
        params.apf_robot_gain,
        params.apf_influence_m,
        params.apf_min_gap_m,
    )
    assert np.all(force == 0.0)
    # The same formation shrunk until its closest pair is 5 % inside the rule does repel.
    body_m = scenario.robot_body.body_radius_m
    shrink = 0.95 * (2 * body_m + params.apf_influence_m) / centre_m[others].min()
    squeezed = repulsive_force(
        direction, shrink * centre_m - 2 * body_m, others,
        params.apf_robot_gain, params.apf_influence_m, params.apf_min_gap_m,
    )  # fmt: skip
    assert np.any(squeezed != 0.0)


@pytest.mark.parametrize("formation", FORMATIONS)
def test_equal_requests_give_identical_files(formation: str) -> None:
    fields = {"robots": 17, "formation": formation, "obstacles": 2, "seed": 5}
    first, _ = _generate(**fields)
    second, _ = _generate(**fields)
    assert first == second


def test_seed_moves_the_starts_not_the_slots() -> None:
    _, a = _generate(robots=12, seed=1)
    _, b = _generate(robots=12, seed=2)
    assert [r.slot for r in a.robots] == [r.slot for r in b.robots]
    assert not np.allclose(a.initial_poses(), b.initial_poses())
    assert (a.seed, b.seed) == (1, 2)


def test_wedge_of_three_is_the_papers_triangle_on_the_papers_circle() -> None:
    _, scenario = _generate(robots=3)
    slots = [(r.slot.distance_m, r.slot.angle_deg) for r in scenario.robots if r.slot]
    assert slots == [(1.2, 150.0), (1.2, -150.0)]
    traj = scenario.trajectory
    assert traj.kind == "circle"
    assert (traj.radius_m, traj.angular_rate_radps) == (1.5, 0.35)
    assert len(scenario.obstacles) == 1


def test_starts_are_away_from_the_slots() -> None:
    _, scenario = _generate(robots=20, formation="grid", spacing_m=1.5)
    offsets = np.hypot(*(scenario.initial_poses()[:, :2] - _slots_at_start(scenario)).T)
    assert offsets.min() >= 0.3 * 1.5 - 1e-3
    assert offsets.max() <= 0.6 * 1.5 + 1e-3


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
def test_the_path_grows_with_the_formation_at_the_same_speed(trajectory: str) -> None:
    _, small = _generate(robots=3, trajectory=trajectory)
    _, large = _generate(robots=41, trajectory=trajectory)
    extent_m = max(r.slot.distance_m for r in large.robots if r.slot)
    assert extent_m == pytest.approx(20 * 1.2)

    def size_and_peak_speed(scenario: Scenario) -> tuple[float, float]:
        t = np.linspace(0.0, 400.0, 40_001)
        pose, rate = scenario.trajectory.build().evaluate(t)
        return float(np.abs(pose[:, :2]).max()), float(np.hypot(rate[:, 0], rate[:, 1]).max())

    small_size, small_speed = size_and_peak_speed(small)
    large_size, large_speed = size_and_peak_speed(large)
    assert small_size < extent_m <= large_size + 1e-6
    assert large_speed == pytest.approx(small_speed, rel=1e-3)


def test_obstacles_lie_on_the_leaders_path() -> None:
    _, scenario = _generate(robots=6, obstacles=3)
    assert len(scenario.obstacles) == 3
    t = np.linspace(0.0, 2 * math.pi / scenario.trajectory.angular_rate_radps, 20_000)  # type: ignore[union-attr]
    path, _ = scenario.trajectory.build().evaluate(t)
    for obstacle in scenario.obstacles:
        gap = np.hypot(*(path[:, :2] - np.asarray(obstacle.position_m)).T).min()
        assert gap < obstacle.radius_m  # the leader has to avoid it


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"robots": 0}, "--robots"),
        ({"robots": 10_000}, "--robots"),
        ({"robots": 3, "formation": "star"}, "unknown formation"),
        ({"robots": 3, "trajectory": "spiral"}, "unknown trajectory"),
        ({"robots": 3, "spacing_m": 0.99}, "--spacing-m"),
        ({"robots": 3, "spacing_m": math.nan}, "--spacing-m"),
        ({"robots": 3, "speed_mps": 3.0}, "--speed-mps"),
        ({"robots": 3, "speed_mps": -0.1}, "--speed-mps"),
        ({"robots": 3, "size_m": 0.0}, "--size-m"),
        ({"robots": 3, "obstacles": -1}, "--obstacles"),
        ({"robots": 3, "obstacles": 12}, "do not fit"),
        ({"robots": 3, "seed": -4}, "--seed"),
        ({"robots": 3, "duration_s": 0.0}, "--duration"),
        ({"robots": 3, "name": "no spaces"}, "--name"),
    ],
)
def test_bad_requests_are_refused_in_one_line(fields: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioGenerationError) as caught:
        _generate(**fields)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_the_obstacle_count_that_fits_is_the_one_named() -> None:
    with pytest.raises(ScenarioGenerationError, match=r"only (\d+) do") as caught:
        _generate(robots=4, obstacles=20)
    fitting = int(re.search(r"only (\d+) do", str(caught.value)).group(1))  # type: ignore[union-attr]
    _, scenario = _generate(robots=4, obstacles=fitting)
    assert len(scenario.obstacles) == fitting
    with pytest.raises(ScenarioGenerationError):
        _generate(robots=4, obstacles=fitting + 1)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        # Before: ZeroDivisionError (the angular rate was written as 0.0).
        ({"speed_mps": 1e-7}, "--speed-mps 1e-07 is too slow for a circle of 1.5 m"),
        (
            {"trajectory": "lemniscate", "speed_mps": 1e-6},
            "--speed-mps 1e-06 is too slow for a lemniscate",
        ),
        # Before: named trajectory.polyline.speed_mps, duration_s, trajectory.circle.radius_m.
        ({"trajectory": "polyline", "speed_mps": 1e-5}, "--speed-mps 1e-05 is too slow"),
        ({"duration_s": 1e-5}, "--duration must be at least one control period (0.01 s"),
        ({"duration_s": 0.004}, "--duration must be at least one control period"),
        ({"duration_s": 1e6}, "--duration must be at most 100000 s"),
        ({"size_m": 1e-9}, "--size-m must be at least 0.0001 m"),
    ],
)
def test_a_value_the_file_would_round_to_nothing_is_refused_naming_the_flag(
    fields: dict[str, object], message: str
) -> None:
    with pytest.raises(ScenarioGenerationError) as caught:
        generate_scenario_text(GenerateRequest(robots=3, **fields))  # type: ignore[arg-type]
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
def test_a_speed_too_slow_for_the_file_names_the_slowest_that_is_not(trajectory: str) -> None:
    with pytest.raises(ScenarioGenerationError, match=r"give at least (\S+) m/s") as caught:
        generate_scenario_text(GenerateRequest(robots=3, trajectory=trajectory, speed_mps=1e-9))
    match = re.search(r"give at least (\S+) m/s", str(caught.value))
    assert match is not None
    _, scenario = _generate(robots=3, trajectory=trajectory, speed_mps=float(match[1]))
    assert scenario.trajectory.kind == trajectory

"""Eqs. 23 and 25 (the force is the potential's negative gradient, clipped near contact), the
avoidance round other robots (circulation, keeping the desired point clear) and the approach
guard on the commanded velocity (apf.py)."""

from dataclasses import replace

import numpy as np
import pytest

from robot_firmware.control.apf import (
    circulation,
    circulation_side,
    clip_norm,
    keep_clear,
    limit_approach,
    repulsive_force,
    repulsive_potential,
)
from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    RobotRole,
    control_step,
)
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from robot_firmware.control.kinematics import pose_rate_from_wheel_speeds

GAIN = 0.005
INFLUENCE_M = 0.4
BODY_RADIUS_M = 0.3


def _potential_at(q: np.ndarray, sources: np.ndarray, radii: np.ndarray) -> float:
    d = q - sources
    gap = np.hypot(d[:, 0], d[:, 1]) - BODY_RADIUS_M - radii
    return float(repulsive_potential(gap, np.ones(len(radii), dtype=bool), GAIN, INFLUENCE_M))


def _force_at(q: np.ndarray, sources: np.ndarray, radii: np.ndarray) -> np.ndarray:
    d = q - sources
    dist = np.hypot(d[:, 0], d[:, 1])
    gap = dist - BODY_RADIUS_M - radii
    return repulsive_force(
        d / dist[:, None], gap, np.ones(len(radii), dtype=bool), GAIN, INFLUENCE_M, 1e-6
    )


def test_force_is_negative_numerical_gradient_of_potential() -> None:
    rng = np.random.default_rng(6)
    checked = 0
    for _ in range(400):
        sources = rng.uniform(-1, 1, size=(3, 2))
        radii = rng.uniform(0.05, 0.3, size=3)
        q = rng.uniform(-1.5, 1.5, size=2)
        gaps = np.hypot(*(q - sources).T) - BODY_RADIUS_M - radii
        # Stay clear of contact and of the non-smooth rim ρ = ρ₀.
        if np.any(gaps < 0.05) or np.any(np.abs(gaps - INFLUENCE_M) < 1e-3):
            continue
        h = 1e-6
        grad = np.array(
            [
                (_potential_at(q + e, sources, radii) - _potential_at(q - e, sources, radii))
                / (2 * h)
                for e in (np.array([h, 0.0]), np.array([0.0, h]))
            ]
        )
        np.testing.assert_allclose(_force_at(q, sources, radii), -grad, rtol=1e-5, atol=1e-7)
        checked += 1
    assert checked > 50


def test_sources_beyond_influence_do_not_repel() -> None:
    force = repulsive_force(
        np.array([[1.0, 0.0], [0.0, 1.0]]),
        np.array([INFLUENCE_M + 0.01, 2.0]),
        np.array([True, True]),
        GAIN,
        INFLUENCE_M,
        0.01,
    )
    np.testing.assert_array_equal(force, [0.0, 0.0])


def test_invalid_sources_are_ignored_and_pairs_sum() -> None:
    directions = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
    gaps = np.array([0.2, 0.2, 0.1])
    both = repulsive_force(directions, gaps, np.array([True, True, False]), 1.0, 0.4, 0.01)
    np.testing.assert_allclose(both, [0.0, 0.0], atol=1e-12)
    one = repulsive_force(directions, gaps, np.array([True, False, False]), 1.0, 0.4, 0.01)
    assert one[0] > 0.0 and one[1] == 0.0


def test_force_is_floored_near_contact_and_clipped() -> None:
    direction = np.array([[1.0, 0.0]])
    at_floor = repulsive_force(direction, np.array([0.02]), np.array([True]), GAIN, 0.4, 0.02)
    inside = repulsive_force(direction, np.array([-0.05]), np.array([True]), GAIN, 0.4, 0.02)
    np.testing.assert_allclose(inside, at_floor)
    clipped = clip_norm(np.array([[3.0, 4.0], [0.3, 0.4]]), 1.0)
    np.testing.assert_allclose(clipped, [[0.6, 0.8], [0.3, 0.4]])


def test_eqs23_and_25_at_gaps_worked_by_hand() -> None:
    # ς = 1, ρ₀ = 0.4 m, floor 0.05 m. One source 0.2 m away along +x, one 0.1 m away along +y:
    # eq. 23: U = ½(1/0.2 − 1/0.4)² + ½(1/0.1 − 1/0.4)² = ½·2.5² + ½·7.5² = 3.125 + 28.125;
    # eq. 25: |F| = (1/ρ − 1/ρ₀)/ρ²: 2.5/0.04 = 62.5 along +x and 7.5/0.01 = 750 along +y.
    directions = np.array([[1.0, 0.0], [0.0, 1.0]])
    gaps = np.array([0.2, 0.1])
    both = np.array([True, True])
    potential = repulsive_potential(gaps, both, 1.0, 0.4)
    np.testing.assert_allclose(potential, 31.25, rtol=1e-12)
    force = repulsive_force(directions, gaps, both, 1.0, 0.4, 0.05)
    np.testing.assert_allclose(force, [62.5, 750.0], rtol=1e-12)
    # Closer than the floor (0.02 m < 0.05 m), ρ is taken as 0.05: (20 − 2.5)/0.0025 = 7000.
    floored = repulsive_force(directions[:1], np.array([0.02]), both[:1], 1.0, 0.4, 0.05)
    np.testing.assert_allclose(floored, [7000.0, 0.0], rtol=1e-12)


# -- round other robots: circulation and keeping clear (apf.py) ------------------------------


def test_circulation_turns_the_radial_direction_by_a_quarter_turn() -> None:
    assert circulation(1.0, 0.0, 0.5) == (-0.0, 0.5)  # east of the source: pushed north
    assert circulation(0.0, 1.0, -0.5) == (0.5, -0.0)  # clockwise: north of it, pushed east


def test_circulation_side_follows_the_lean_and_ties_go_anticlockwise() -> None:
    assert circulation_side(1.0, 0.0, 0.2, 0.3) == 1.0
    assert circulation_side(1.0, 0.0, 0.2, -0.3) == -1.0
    assert circulation_side(1.0, 0.0, -1.0, 0.0) == 1.0  # straight back at the source


def test_keep_clear_pushes_a_desired_point_out_to_the_reach_and_drops_the_inward_velocity() -> None:
    push_m, inward_mps = keep_clear(0.5, 0.1, -0.3, 0.2, 1.0, 0.0, 0.7)
    assert push_m == pytest.approx(0.2) and inward_mps == pytest.approx(-0.3)
    assert keep_clear(0.9, 0.0, 0.3, 0.0, 1.0, 0.0, 0.7) == (0.0, 0.0)


def _one_robot_step(
    peer_xy: tuple[float, float],
    stopped: bool,
    reference_xy: tuple[float, float],
    side: float = 0.0,
    params: ControllerParams | None = None,
    reference_rate: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """One leader at the origin, localised, one peer; returns the repulsion, desired pose, the
    side kept for the peer and the commanded world velocity (x, y)."""
    params = ControllerParams() if params is None else params
    state = ControllerState.initial((), len(params.sonar_beam_angles_rad))
    state = replace(
        state,
        estimator=replace(state.estimator, localised=np.array(True)),
        circulation_side=np.array([side]),
    )
    inputs = ControlInputs(
        t_s=1.0,
        encoder_counts=np.zeros(4, dtype=np.int64),
        fix_pose=np.zeros(3),
        fix_valid=np.array(False),
        sonar_range_m=np.full(12, np.inf),
        sonar_fresh=False,
        peer_pose=np.array([[peer_xy[0], peer_xy[1], 0.0]]),
        peer_rate=np.zeros((1, 3)),
        peer_stamp_s=np.array([1.0]),
        peer_valid=np.array([True]),
        peer_is_leader=np.array([False]),
        reference_pose=np.array([reference_xy[0], reference_xy[1], 0.0]),
        reference_rate=np.array([reference_rate[0], reference_rate[1], 0.0]),
        peer_stopped=np.array([stopped]),
    )
    role = RobotRole(np.array(True), np.array(0.0), np.array(0.0))
    new_state, out = control_step(
        state, inputs, role, FuzzyParameters.table2_defaults().rule_base(), params
    )
    assert new_state.circulation_side is not None
    rate = pose_rate_from_wheel_speeds(out.wheel_speed_radps * params.wheel_radius_m, 0.0, 0.25)
    return out.repulsion_mps, out.desired_pose, float(new_state.circulation_side[0]), rate[:2]


def test_a_stopped_robot_dead_ahead_is_gone_round_not_stalled_in_front_of() -> None:
    # The reference lies beyond a stopped robot 0.7 m east, a little to the north of the line.
    # Seen from the stopped robot, this one is to its west: going round it by the north is
    # clockwise (side -1).
    repulsion, _, side, _ = _one_robot_step((0.7, 0.0), True, (1.5, 0.05))
    assert repulsion[0] < 0.0 and repulsion[1] > 0.0  # pushed back, and round to the north
    assert side == -1.0
    repulsion, _, side, _ = _one_robot_step((0.7, 0.0), True, (1.5, -0.05))
    assert repulsion[1] < 0.0 and side == 1.0
    # Chosen once per encounter: a goal that leans the other way later does not flip it.
    repulsion, _, side, _ = _one_robot_step((0.7, 0.0), True, (1.5, -0.05), side=-1.0)
    assert repulsion[1] > 0.0 and side == -1.0
    # Out of reach, the side is forgotten.
    assert _one_robot_step((1.5, 0.0), True, (3.0, 0.05), side=1.0)[2] == 0.0


def test_a_live_robot_is_gone_round_anticlockwise_and_no_side_is_kept() -> None:
    repulsion, _, side, _ = _one_robot_step((0.7, 0.0), False, (1.5, -0.05))
    assert repulsion[1] < 0.0 and side == 0.0  # anticlockwise round a robot to the east: south
    repulsion, _, _, _ = _one_robot_step((0.0, 0.7), False, (0.0, 1.5))
    assert repulsion[0] > 0.0  # round a robot to the north: pushed east


def test_the_desired_point_is_kept_clear_of_a_robot_it_runs_into() -> None:
    params = ControllerParams()
    reach_m = 2.0 * params.body_radius_m + params.apf_clearance_m
    _, desired, _, _ = _one_robot_step((0.7, 0.0), True, (0.7, 0.0))  # the reference is in it
    assert 0.7 - desired[0] >= reach_m - 1e-9
    _, clear, _, _ = _one_robot_step((0.7, 0.0), True, (-0.2, 0.0))  # already clear: untouched
    assert clear[0] == pytest.approx(-0.2, abs=0.02)


def test_limit_approach_cuts_only_the_part_towards_the_body() -> None:
    # The body lies west (the direction from it to the robot is +x); the gap is 0.13 m.
    vx, vy, cut = limit_approach(-0.5, 0.2, 1.0, 0.0, 0.13, 1.0, 0.0, 0.03, 0.25)
    assert cut and vx == pytest.approx(-0.4) and vy == 0.2  # 0.1 m / 0.25 s towards it, at most
    assert limit_approach(0.3, 0.2, 1.0, 0.0, 0.13, 1.0, 0.0, 0.03, 0.25) == (0.3, 0.2, False)
    vx, _, _ = limit_approach(-0.5, 0.0, 1.0, 0.0, 0.13, 0.5, 0.0, 0.03, 0.25)
    assert vx == pytest.approx(-0.2)  # half the budget towards a live robot
    vx, _, cut = limit_approach(0.0, 0.0, 1.0, 0.0, 0.01, 1.0, 0.0, 0.03, 0.25)
    assert cut and vx == pytest.approx(0.08)  # inside the kept gap: backed off


def test_limit_approach_takes_up_what_the_other_robot_does_not() -> None:
    # A live robot to the west coming at 0.3 m/s, more than its half (0.2 m/s) of the budget:
    # this one may approach at 0.4 - 0.3 = 0.1 m/s only ...
    vx, _, _ = limit_approach(-0.5, 0.0, 1.0, 0.0, 0.13, 0.5, 0.3, 0.03, 0.25)
    assert vx == pytest.approx(-0.1)
    # ... and backs off when it comes faster than the whole budget.
    vx, _, _ = limit_approach(0.0, 0.0, 1.0, 0.0, 0.13, 0.5, 0.7, 0.03, 0.25)
    assert vx == pytest.approx(0.3)
    # One that keeps its half leaves this one its own half.
    vx, _, _ = limit_approach(-0.5, 0.0, 1.0, 0.0, 0.13, 0.5, 0.1, 0.03, 0.25)
    assert vx == pytest.approx(-0.2)


def test_the_approach_guard_keeps_a_robot_from_driving_into_a_stopped_one() -> None:
    # A reference racing east straight through a stopped robot whose body is 5 cm away, with
    # the field reaching only 1 cm: the guard alone stands between them.
    guarded = ControllerParams(apf_influence_m=0.01)
    unguarded = guarded.model_copy(update={"approach_guard": False})
    peer, reference, rate = (0.65, 0.0), (1.5, 0.0), (0.5, 0.0)
    *_, free = _one_robot_step(peer, True, reference, params=unguarded, reference_rate=rate)
    *_, held = _one_robot_step(peer, True, reference, params=guarded, reference_rate=rate)
    allowed_mps = (0.05 - guarded.guard_gap_m) / guarded.guard_time_constant_s
    assert free[0] > allowed_mps + 0.1
    assert held[0] == pytest.approx(allowed_mps, abs=1e-9)


def test_a_copy_of_the_parameters_computes_its_own_kernel_constants() -> None:
    params = ControllerParams()
    assert params.constants.guard_enabled
    assert not params.model_copy(update={"approach_guard": False}).constants.guard_enabled

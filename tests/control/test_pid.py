import numpy as np

from robot_firmware.control.kinematics import pose_rate_from_wheel_speeds
from robot_firmware.control.pid import (
    PidState,
    filtered_error_rate,
    redundant_pid_law,
    tracking_error,
)

GEOMETRY = {"wheel_base_m": 0.25, "wheel_radius_m": 0.05, "max_wheel_speed_radps": 10.0}


def _law(state: PidState, error: np.ndarray, desired_rate: np.ndarray, integrate: bool = True):
    gains = np.full(3, 2.0)
    return redundant_pid_law(
        state,
        error,
        np.zeros(3),
        desired_rate,
        np.array(0.3),
        gains,
        gains,
        np.zeros(3),
        np.array(integrate),
        0.01,
        np.full(3, 0.05),
        **GEOMETRY,
    )


def test_zero_error_follows_feedforward_exactly() -> None:
    desired = np.array([0.1, -0.2, 0.3])
    _, wheels = _law(PidState.zeros(()), np.zeros(3), desired)
    body = pose_rate_from_wheel_speeds(wheels * GEOMETRY["wheel_radius_m"], np.array(0.3), 0.25)
    np.testing.assert_allclose(body, desired, atol=1e-12)


def test_proportional_term_opposes_error() -> None:
    _, wheels = _law(PidState.zeros(()), np.array([0.1, 0.0, 0.0]), np.zeros(3), integrate=False)
    body = pose_rate_from_wheel_speeds(wheels * GEOMETRY["wheel_radius_m"], np.array(0.3), 0.25)
    np.testing.assert_allclose(body, [-0.2, 0.0, 0.0], atol=1e-12)


def test_saturation_scales_all_wheels_and_keeps_direction() -> None:
    state, wheels = _law(PidState.zeros(()), np.zeros(3), np.array([3.0, 1.0, 0.0]))
    assert np.max(np.abs(wheels)) == np.float64(GEOMETRY["max_wheel_speed_radps"])
    body = pose_rate_from_wheel_speeds(wheels, np.array(0.3), 0.25)
    assert np.isclose(body[0] / body[1], 3.0)
    assert bool(state.saturated)


def test_integral_is_clamped_and_frozen_while_saturated_or_held() -> None:
    state = PidState.zeros(())
    for _ in range(1000):
        state, _ = _law(state, np.array([0.2, 0.0, 0.0]), np.zeros(3))
    assert np.isclose(state.integral[0], 0.05)
    held = PidState(
        integral=np.array([0.01, 0.0, 0.0]),
        previous_error=np.zeros(3),
        error_rate=np.zeros(3),
        saturated=np.array(True),
        started=np.array(True),
    )
    after, _ = _law(held, np.array([0.2, 0.0, 0.0]), np.zeros(3))
    np.testing.assert_array_equal(after.integral, held.integral)
    not_integrating, _ = _law(PidState.zeros(()), np.array([0.2, 0.0, 0.0]), np.zeros(3), False)
    np.testing.assert_array_equal(not_integrating.integral, 0.0)


def test_error_rate_is_filtered_and_wraps_heading() -> None:
    state = PidState(
        integral=np.zeros(3),
        previous_error=np.array([0.0, 0.0, np.pi - 0.01]),
        error_rate=np.zeros(3),
        saturated=np.array(False),
        started=np.array(True),
    )
    error = np.array([0.01, 0.0, -np.pi + 0.01])
    rate = filtered_error_rate(state, error, 0.01, 0.0)
    np.testing.assert_allclose(rate, [1.0, 0.0, 2.0], atol=1e-9)
    smoothed = filtered_error_rate(state, error, 0.01, 0.03)
    np.testing.assert_allclose(smoothed, 0.25 * rate, atol=1e-9)
    first_tick = filtered_error_rate(PidState.zeros(()), error, 0.01, 0.0)
    np.testing.assert_array_equal(first_tick, 0.0)


def test_tracking_error_wraps_heading() -> None:
    e = tracking_error(np.array([1.0, 2.0, 3.1]), np.array([0.5, 2.5, -3.1]))
    np.testing.assert_allclose(e, [0.5, -0.5, 6.2 - 2 * np.pi], atol=1e-12)


DT_S = 0.01
FILTER_TIME_CONSTANT_S = 0.03  # α = 0.03 / (0.03 + 0.01) = 0.75 on the previous rate
THETA_RAD = np.array(0.3)


def _tick(
    state: PidState,
    error: np.ndarray,
    kp: float,
    ki: float,
    kd: np.ndarray,
    desired_rate: np.ndarray | None = None,
) -> tuple[PidState, np.ndarray, np.ndarray]:
    """One control tick as the controller runs it: ė from the filter, then eq. 14.

    Returns the new state, ė and the body-rate command recovered from the wheel speeds (eq. 11).
    """
    feedforward = np.zeros(3) if desired_rate is None else desired_rate
    rate = filtered_error_rate(state, error, DT_S, FILTER_TIME_CONSTANT_S)
    new_state, wheels = redundant_pid_law(
        state,
        error,
        rate,
        feedforward,
        THETA_RAD,
        np.full(3, kp),
        np.full(3, ki),
        kd,
        np.array(True),
        DT_S,
        np.full(3, 0.05),
        **GEOMETRY,
    )
    assert not bool(new_state.saturated)
    body = pose_rate_from_wheel_speeds(
        wheels * GEOMETRY["wheel_radius_m"], THETA_RAD, GEOMETRY["wheel_base_m"]
    )
    return new_state, rate, body


def test_derivative_term_of_eq14_over_two_ticks_of_a_known_error_sequence() -> None:
    # K_P = K_I = 0, K_D = (0.4, 0.4, 0.2): the command is -K_D·ė alone.
    kd = np.array([0.4, 0.4, 0.2])
    e0 = np.array([0.02, -0.01, 0.0])
    e1 = np.array([0.03, -0.01, -0.02])
    e2 = np.array([0.025, 0.0, -0.02])
    state = PidState.zeros(())
    # Tick 0: no previous error yet, ė = 0, command 0.
    state, rate, body = _tick(state, e0, 0.0, 0.0, kd)
    np.testing.assert_array_equal(rate, 0.0)
    np.testing.assert_allclose(body, 0.0, atol=1e-15)
    # Tick 1: backward difference (e1 - e0)/0.01 = (1.0, 0.0, -2.0);
    # ė = 0.75·0 + 0.25·(1.0, 0.0, -2.0) = (0.25, 0.0, -0.5);
    # u = -(0.4·0.25, 0.4·0, 0.2·(-0.5)) = (-0.1, 0.0, 0.1).
    state, rate, body = _tick(state, e1, 0.0, 0.0, kd)
    np.testing.assert_allclose(rate, [0.25, 0.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(body, [-0.1, 0.0, 0.1], atol=1e-12)
    # Tick 2: backward difference (e2 - e1)/0.01 = (-0.5, 1.0, 0.0);
    # ė = 0.75·(0.25, 0.0, -0.5) + 0.25·(-0.5, 1.0, 0.0) = (0.0625, 0.25, -0.375);
    # u = -(0.4·0.0625, 0.4·0.25, 0.2·(-0.375)) = (-0.025, -0.1, 0.075).
    state, rate, body = _tick(state, e2, 0.0, 0.0, kd)
    np.testing.assert_allclose(rate, [0.0625, 0.25, -0.375], atol=1e-12)
    np.testing.assert_allclose(body, [-0.025, -0.1, 0.075], atol=1e-12)
    np.testing.assert_allclose(state.error_rate, [0.0625, 0.25, -0.375], atol=1e-12)
    np.testing.assert_array_equal(state.previous_error, e2)


def test_eq14_with_all_three_terms_and_feedforward() -> None:
    # K_P = 2, K_I = 1, K_D = 0.4 on every axis, feedforward Ẏ_d = (0.05, 0.0, -0.1).
    kd = np.full(3, 0.4)
    feedforward = np.array([0.05, 0.0, -0.1])
    e0 = np.array([0.02, -0.01, 0.0])
    e1 = np.array([0.03, -0.01, -0.02])
    state, _, body0 = _tick(PidState.zeros(()), e0, 2.0, 1.0, kd, feedforward)
    # Tick 0: ∫e = 0.01·e0 = (0.0002, -0.0001, 0), ė = 0:
    # u = (0.05, 0, -0.1) - 2·(0.02, -0.01, 0) - (0.0002, -0.0001, 0) = (0.0098, 0.0201, -0.1).
    np.testing.assert_allclose(body0, [0.0098, 0.0201, -0.1], atol=1e-12)
    state, _, body1 = _tick(state, e1, 2.0, 1.0, kd, feedforward)
    # Tick 1: ∫e = (0.0002, -0.0001, 0) + 0.01·e1 = (0.0005, -0.0002, -0.0002),
    # ė = 0.25·(1.0, 0.0, -2.0) = (0.25, 0.0, -0.5):
    # u = (0.05, 0, -0.1) - 2·(0.03, -0.01, -0.02) - (0.0005, -0.0002, -0.0002)
    #     - 0.4·(0.25, 0.0, -0.5)
    #   = (0.05 - 0.06 - 0.0005 - 0.1, 0 + 0.02 + 0.0002 - 0, -0.1 + 0.04 + 0.0002 + 0.2)
    #   = (-0.1105, 0.0202, 0.1402).
    np.testing.assert_allclose(state.integral, [0.0005, -0.0002, -0.0002], atol=1e-15)
    np.testing.assert_allclose(body1, [-0.1105, 0.0202, 0.1402], atol=1e-12)


def test_derivative_term_opposes_a_growing_error_and_scales_with_kd() -> None:
    # The error grows at 1 m/s along x and shrinks at 2 rad/s in heading; no filter memory.
    started = PidState(
        integral=np.zeros(3),
        previous_error=np.array([0.01, 0.0, 0.05]),
        error_rate=np.zeros(3),
        saturated=np.array(False),
        started=np.array(True),
    )
    error = np.array([0.02, 0.0, 0.03])
    commands = {}
    for kd_value in (0.0, 0.2, 0.4):
        _, rate, body = _tick(started, error, 0.0, 0.0, np.full(3, kd_value))
        commands[kd_value] = body
    # ė = 0.25·((0.02 - 0.01)/0.01, 0, (0.03 - 0.05)/0.01) = (0.25, 0, -0.5).
    np.testing.assert_allclose(rate, [0.25, 0.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(commands[0.0], 0.0, atol=1e-15)
    # The command pushes against the error's motion: -x while e_x grows, +θ while e_θ falls.
    assert commands[0.2][0] < 0.0 and commands[0.2][2] > 0.0
    np.testing.assert_allclose(commands[0.2], [-0.05, 0.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(commands[0.4], 2.0 * commands[0.2], atol=1e-12)

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

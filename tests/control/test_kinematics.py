import numpy as np
import pytest

from robot_firmware.control.kinematics import (
    kinematics_matrix,
    pose_rate_from_wheel_speeds,
    pseudo_inverse,
    wheel_speeds_from_pose_rate,
)

WHEEL_BASE_M = 0.25


def test_pseudo_inverse_is_left_inverse_over_random_headings() -> None:
    theta = np.random.default_rng(1).uniform(-10.0, 10.0, size=2000)
    product = pseudo_inverse(theta, WHEEL_BASE_M) @ kinematics_matrix(theta, WHEEL_BASE_M)
    np.testing.assert_allclose(product, np.broadcast_to(np.eye(3), product.shape), atol=1e-12)


def test_paper_eq10_first_row_does_not_recover_x_rate() -> None:
    # Eq. 10 as printed divides by squared trig terms; its first row times P(θ) is not [1, 0, 0],
    # while the corrected pseudo-inverse's is.
    theta = 0.3
    s, c = np.sin(theta + np.pi / 4), np.cos(theta + np.pi / 4)
    printed_first_row = np.array([-s / c**2, -c / -(s**2), s / -(c**2), c / s**2])
    p = kinematics_matrix(theta, WHEEL_BASE_M)
    assert not np.allclose(printed_first_row @ p, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(
        pseudo_inverse(theta, WHEEL_BASE_M)[0] @ p, [1.0, 0.0, 0.0], atol=1e-12
    )


def test_gram_matrix_matches_design() -> None:
    theta = np.linspace(-3, 3, 13)
    p = kinematics_matrix(theta, WHEEL_BASE_M)
    gram = np.swapaxes(p, -1, -2) @ p
    expected = np.diag([2.0, 2.0, 4.0 * WHEEL_BASE_M**2])
    np.testing.assert_allclose(gram, np.broadcast_to(expected, gram.shape), atol=1e-12)


@pytest.mark.parametrize("shape", [(), (5,), (4, 3)])
def test_elementwise_forms_equal_matrix_forms(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(2)
    theta = rng.uniform(-np.pi, np.pi, size=shape)
    rate = rng.normal(size=shape + (3,))
    wheels = wheel_speeds_from_pose_rate(rate, theta, WHEEL_BASE_M)
    expected = (kinematics_matrix(theta, WHEEL_BASE_M) @ rate[..., None])[..., 0]
    np.testing.assert_allclose(wheels, expected, atol=1e-12)
    back = pose_rate_from_wheel_speeds(wheels, theta, WHEEL_BASE_M)
    np.testing.assert_allclose(back, rate, atol=1e-12)
    v = rng.normal(size=shape + (4,))
    expected_rate = (pseudo_inverse(theta, WHEEL_BASE_M) @ v[..., None])[..., 0]
    np.testing.assert_allclose(
        pose_rate_from_wheel_speeds(v, theta, WHEEL_BASE_M), expected_rate, atol=1e-12
    )


def test_pure_spin_drives_all_wheels_equally() -> None:
    wheels = wheel_speeds_from_pose_rate(np.array([0.0, 0.0, 2.0]), np.array(0.7), WHEEL_BASE_M)
    np.testing.assert_allclose(wheels, np.full(4, 2.0 * WHEEL_BASE_M))


def test_eq9_at_a_heading_worked_by_hand() -> None:
    # θ = π/4, so δ + θ = π/2: sin = 1, cos = 0 and eq. 9's P(θ) is
    # [[-1, 0, L], [0, -1, L], [1, 0, L], [0, 1, L]] with L = 0.25 m.
    # For (ẋ, ẏ, θ̇) = (0.2, -0.1, 0.4): L·θ̇ = 0.1, rims (-0.2 + 0.1, 0.1 + 0.1, 0.2 + 0.1,
    # -0.1 + 0.1) = (-0.1, 0.2, 0.3, 0.0) m/s.
    theta = np.array(np.pi / 4)
    np.testing.assert_allclose(
        kinematics_matrix(theta, WHEEL_BASE_M),
        [[-1.0, 0.0, 0.25], [0.0, -1.0, 0.25], [1.0, 0.0, 0.25], [0.0, 1.0, 0.25]],
        atol=1e-15,
    )
    rate = np.array([0.2, -0.1, 0.4])
    wheels = wheel_speeds_from_pose_rate(rate, theta, WHEEL_BASE_M)
    np.testing.assert_allclose(wheels, [-0.1, 0.2, 0.3, 0.0], atol=1e-15)
    # Eq. 11 with P# of DESIGN.md §6 (s = 1, c = 0): ẋ = (v3 − v1)/2 = 0.2,
    # ẏ = (v4 − v2)/2 = -0.1, θ̇ = Σv/(4L) = 0.4/1.0 = 0.4.
    np.testing.assert_allclose(
        pose_rate_from_wheel_speeds(np.array([-0.1, 0.2, 0.3, 0.0]), theta, WHEEL_BASE_M),
        rate,
        atol=1e-15,
    )

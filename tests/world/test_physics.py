import numpy as np

from swarm_config.body import BodyParams
from world.physics import (
    BodyState,
    encoder_counts,
    resolve_contacts,
    step_bodies,
)

NO_SLIP = BodyParams(slip_std=0.0)


def _euler_reference(state: BodyState, duty: np.ndarray, total_s: float, steps: int) -> BodyState:
    """Explicit Euler on the ODEs with a tiny step: what '1 kHz or better' integration gives."""
    p = NO_SLIP
    pose = state.pose.astype(float).copy()
    wheel = state.wheel_speed_radps.astype(float).copy()
    angle = state.wheel_angle_rad.astype(float).copy()
    h = total_s / steps
    target = np.clip(duty, -1, 1) * p.motor_no_load_speed_radps
    for _ in range(steps):
        v = p.wheel_radius_m * wheel
        phi = pose[2] + np.pi / 4
        s, c = np.sin(phi), np.cos(phi)
        a = 0.5 * (v[2] - v[0])
        b = 0.5 * (v[3] - v[1])
        pose = pose + h * np.array([s * a + c * b, -c * a + s * b, v.sum() / (4 * p.wheel_base_m)])
        angle = angle + h * wheel
        wheel = wheel + h * (target - wheel) / p.motor_time_constant_s
    return BodyState(pose=pose, wheel_speed_radps=wheel, wheel_angle_rad=angle, slip=state.slip)


def test_one_control_period_step_equals_fine_integration() -> None:
    start = BodyState(
        pose=np.array([0.3, -0.2, 1.0]),
        wheel_speed_radps=np.array([5.0, -3.0, 2.0, 8.0]),
        wheel_angle_rad=np.zeros(4),
        slip=np.zeros(4),
    )
    duty = np.array([0.9, 0.2, -0.7, 0.4])
    exact = start
    for _ in range(20):  # 0.2 s in 10 ms steps, as the batch simulator does
        exact = step_bodies(exact, duty, 0.01, np.zeros(4), NO_SLIP)
    fine = _euler_reference(start, duty, 0.2, 200_000)  # 1 µs Euler
    np.testing.assert_allclose(exact.pose, fine.pose, atol=2e-6)
    np.testing.assert_allclose(exact.wheel_speed_radps, fine.wheel_speed_radps, atol=1e-4)
    np.testing.assert_allclose(exact.wheel_angle_rad, fine.wheel_angle_rad, atol=1e-5)
    kilohertz = start
    for _ in range(200):
        kilohertz = step_bodies(kilohertz, duty, 0.001, np.zeros(4), NO_SLIP)
    np.testing.assert_allclose(exact.pose, kilohertz.pose, atol=1e-9)


def test_motor_settles_at_duty_times_no_load_speed_and_saturates() -> None:
    state = BodyState.at_rest(np.zeros(3))
    for _ in range(200):
        state = step_bodies(state, np.array([0.5, -0.25, 3.0, -3.0]), 0.01, np.zeros(4), NO_SLIP)
    np.testing.assert_allclose(
        state.wheel_speed_radps, NO_SLIP.motor_no_load_speed_radps * np.array([0.5, -0.25, 1, -1])
    )


def test_slip_statistics_do_not_depend_on_step_length() -> None:
    params = BodyParams(slip_std=0.05, slip_correlation_time_s=0.1)
    rng = np.random.default_rng(10)
    finals = []
    for dt, steps in ((0.01, 100), (0.001, 1000)):
        state = BodyState.at_rest(np.zeros((4000, 3)))
        for _ in range(steps):
            state = step_bodies(
                state, np.zeros((4000, 4)), dt, rng.standard_normal((4000, 4)), params
            )
        finals.append(np.std(state.slip))
    np.testing.assert_allclose(finals, 0.05 * np.sqrt(1 - np.exp(-20)), rtol=0.05)


def test_encoder_quantises_to_whole_counts() -> None:
    counts = encoder_counts(np.array([0.0, 2 * np.pi, -1e-9, np.pi / 1024 * 1.5]), 2048)
    np.testing.assert_array_equal(counts, [0, 2048, -1, 1])
    assert counts.dtype == np.int64


def test_overlapping_bodies_are_pushed_apart_and_reported() -> None:
    positions = np.array([[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]])
    obstacles = np.array([[3.0, 0.35]])
    fixed, report = resolve_contacts(positions, 0.3, obstacles, np.array([0.1]))
    assert report.robot_robot[0, 1] and report.robot_robot[1, 0]
    assert not report.robot_robot[0, 2]
    assert report.robot_obstacle[2, 0] and not report.robot_obstacle[0, 0]
    assert np.isclose(np.hypot(*(fixed[1] - fixed[0])), 0.6)
    assert np.isclose(np.hypot(*(fixed[2] - obstacles[0])), 0.4)

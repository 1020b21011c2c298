import numpy as np
import pytest

from robot_firmware.control.trajectories import (
    CircleTrajectory,
    LemniscateTrajectory,
    PolylineTrajectory,
)


def test_circle_is_the_papers_reference() -> None:
    # x_d = 1.5 cos(0.35 t), y_d = 1.5 sin(0.35 t), θ_d = π/2 (§IV-B), worked out at the
    # quarter turns t = k·(π/2)/0.35 ≈ k·4.488 s and at one eighth of a turn, t = (π/4)/0.35:
    # the point runs anticlockwise at 1.5 m · 0.35 rad/s = 0.525 m/s, tangent to the circle.
    quarter_s = (np.pi / 2) / 0.35
    t = np.array([0.0, quarter_s, 2 * quarter_s, 3 * quarter_s, 4 * quarter_s, quarter_s / 2])
    pose, rate = CircleTrajectory().evaluate(t)
    half_sqrt2 = np.sqrt(2.0) / 2.0
    np.testing.assert_allclose(
        pose,
        [
            [1.5, 0.0, np.pi / 2],
            [0.0, 1.5, np.pi / 2],
            [-1.5, 0.0, np.pi / 2],
            [0.0, -1.5, np.pi / 2],
            [1.5, 0.0, np.pi / 2],
            [1.5 * half_sqrt2, 1.5 * half_sqrt2, np.pi / 2],
        ],
        atol=1e-12,
    )
    np.testing.assert_allclose(
        rate,
        [
            [0.0, 0.525, 0.0],
            [-0.525, 0.0, 0.0],
            [0.0, -0.525, 0.0],
            [0.525, 0.0, 0.0],
            [0.0, 0.525, 0.0],
            [-0.525 * half_sqrt2, 0.525 * half_sqrt2, 0.0],
        ],
        atol=1e-12,
    )


@pytest.mark.parametrize(
    "trajectory",
    [
        CircleTrajectory(radius_m=1.2, angular_rate_radps=0.5, centre_m=(1, -1), phase_rad=0.3),
        LemniscateTrajectory(),
        PolylineTrajectory(waypoints_m=((0, 0), (2, 0), (2, 1), (0, 1)), speed_mps=0.4),
    ],
)
def test_rate_is_derivative_of_pose(trajectory: object) -> None:
    t = np.linspace(0.013, 40.0, 997)
    h = 1e-6
    pose, rate = trajectory.evaluate(t)  # type: ignore[attr-defined]
    ahead, _ = trajectory.evaluate(t + h)  # type: ignore[attr-defined]
    behind, _ = trajectory.evaluate(t - h)  # type: ignore[attr-defined]
    numeric = (ahead - behind) / (2 * h)
    # Polyline corners are not differentiable; compare away from them.
    smooth = np.all(np.abs(numeric - rate) < 1e-3, axis=-1)
    assert smooth.mean() > 0.98
    assert pose.shape == rate.shape == t.shape + (3,)


def test_open_polyline_stops_at_last_waypoint() -> None:
    path = PolylineTrajectory(waypoints_m=((0, 0), (1, 0)), speed_mps=0.5, closed=False)
    pose, rate = path.evaluate(np.array([1.0, 5.0]))
    np.testing.assert_allclose(pose[:, :2], [[0.5, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(rate[1], 0.0)


def test_polyline_rejects_repeated_waypoints() -> None:
    with pytest.raises(ValueError, match="differ"):
        PolylineTrajectory(waypoints_m=((0, 0), (0, 0), (1, 1)))


def test_one_time_gives_the_same_pose_and_rate_as_that_time_in_an_array() -> None:
    circle = CircleTrajectory(phase_rad=0.3, centre_m=(0.2, -0.1))
    times = np.linspace(0.0, 100.0, 2001)
    poses, rates = circle.evaluate(times)
    for k, t_s in enumerate(times):
        pose, rate = circle.evaluate(float(t_s))
        np.testing.assert_array_equal(pose, poses[k])
        np.testing.assert_array_equal(rate, rates[k])

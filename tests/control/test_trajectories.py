import numpy as np
import pytest

from robot_firmware.control.trajectories import (
    CircleTrajectory,
    LemniscateTrajectory,
    PolylineTrajectory,
)


def test_circle_is_the_papers_reference() -> None:
    t = np.linspace(0, 30, 301)
    pose, _ = CircleTrajectory().evaluate(t)
    np.testing.assert_allclose(pose[:, 0], 1.5 * np.cos(0.35 * t))
    np.testing.assert_allclose(pose[:, 1], 1.5 * np.sin(0.35 * t))
    np.testing.assert_allclose(pose[:, 2], np.pi / 2)


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

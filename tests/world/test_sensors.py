import numpy as np

from swarm_config.sensors import PositioningParams, SonarParams
from world.sensors import pose_fix, sonar_gaps

QUIET = SonarParams(noise_std_m=0.0)
BEAMS = np.deg2rad(np.arange(0, 360, 30.0))
BODY_R = 0.3


def _gaps(pose, centres, radii, valid=None, params=QUIET):
    centres = np.asarray(centres, dtype=float)
    radii = np.asarray(radii, dtype=float)
    valid = np.ones(len(radii), dtype=bool) if valid is None else np.asarray(valid)
    return sonar_gaps(
        np.asarray(pose, dtype=float), BEAMS, centres, radii, valid, BODY_R, np.zeros(12), params
    )


def test_obstacle_ahead_is_seen_at_its_gap_by_the_forward_beam() -> None:
    gaps = _gaps([0, 0, 0], [[2.0, 0.0]], [0.2])
    assert np.isclose(gaps[0], 2.0 - 0.2 - BODY_R)
    assert np.all(np.isinf(gaps[3:10]))


def test_heading_rotates_the_ring() -> None:
    gaps = _gaps([0, 0, np.pi / 2], [[0.0, 2.0]], [0.2])
    assert np.isclose(gaps[0], 1.5)


def test_grazing_obstacle_is_met_along_the_cone_edge() -> None:
    # Centre 25° off the 0° beam: outside its ±15° cone, but the disc reaches into it.
    d, r = 1.5, 0.3
    centre = [d * np.cos(np.deg2rad(25)), d * np.sin(np.deg2rad(25))]
    gaps = _gaps([0, 0, 0], [centre], [r])
    edge = np.deg2rad(10.0)
    expected = d * np.cos(edge) - np.sqrt(r**2 - (d * np.sin(edge)) ** 2) - BODY_R
    # The 30° beam sees the centre inside its cone and reports the nearest surface.
    assert np.isclose(gaps[1], d - r - BODY_R)
    assert np.isclose(gaps[0], expected)
    assert gaps[0] > gaps[1]


def test_out_of_range_and_invalid_targets_give_no_echo() -> None:
    assert np.all(np.isinf(_gaps([0, 0, 0], [[5.0, 0.0]], [0.2])))
    assert np.all(np.isinf(_gaps([0, 0, 0], [[1.0, 0.0]], [0.2], valid=[False])))


def test_nearest_target_wins_and_noise_is_added() -> None:
    gaps = _gaps([0, 0, 0], [[2.0, 0.0], [1.2, 0.0]], [0.2, 0.2])
    assert np.isclose(gaps[0], 0.7)
    noisy = sonar_gaps(
        np.zeros(3),
        BEAMS,
        np.array([[2.0, 0.0]]),
        np.array([0.2]),
        np.array([True]),
        BODY_R,
        np.ones(12),
        SonarParams(noise_std_m=0.01),
    )
    assert np.isclose(noisy[0], 1.51)


def test_pose_fix_noise_has_configured_spread() -> None:
    rng = np.random.default_rng(11)
    params = PositioningParams(position_noise_std_m=0.002, heading_noise_std_rad=0.01)
    fixes = pose_fix(np.zeros((20000, 3)), rng.standard_normal((20000, 3)), params)
    np.testing.assert_allclose(np.std(fixes, axis=0), [0.002, 0.002, 0.01], rtol=0.03)

import numpy as np

from robot_firmware.control.apf import clip_norm, repulsive_force, repulsive_potential

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

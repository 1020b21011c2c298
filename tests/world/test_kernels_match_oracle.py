"""The world's compiled kernels equal the numpy statement of the same math (tests/world/oracle.py).

Seeded random cases with the edge cases mixed in: targets behind the transducer, grazing its
cone, out of range, invalid; links with and without a burst model, cut links, links out of
range; samples with and without reported contacts, near obstacles, with another robot leading.
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm_config.metrics import MetricsConfig
from swarm_config.radio import PROFILES, LinkProfile
from swarm_config.sensors import PositioningParams, SonarParams
from tests.world import oracle
from world.metrics import FormationLayout, MetricsAccumulator
from world.radio import LinkTable, draw_links
from world.sensors import pose_fix, sonar_gaps


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sonar_kernel_equals_the_numpy_sonar(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = rng.normal(0.0, 1.0, (6, 4, 3))
    pose[..., 2] = rng.uniform(-8.0, 8.0, (6, 4))
    beams = np.deg2rad(np.arange(0.0, 360.0, 30.0))
    centres = pose[..., None, :2] + rng.normal(0.0, 1.5, (6, 4, 7, 2))
    radii = rng.uniform(0.05, 0.6, (6, 4, 7))
    valid = rng.random((6, 4, 7)) < 0.8
    noise = rng.standard_normal((6, 4, 12))
    params = SonarParams(noise_std_m=0.02)
    got = sonar_gaps(pose, beams, centres, radii, valid, 0.3, noise, params)
    want = oracle.sonar_gaps(pose, beams, centres, radii, valid, 0.3, noise, params)
    np.testing.assert_array_equal(got, want)
    assert np.isinf(got).any() and np.isfinite(got).any()


def test_fix_kernel_equals_the_numpy_fix() -> None:
    rng = np.random.default_rng(3)
    pose, noise = rng.normal(size=(5, 3, 3)), rng.normal(size=(5, 3, 3))
    params = PositioningParams(position_noise_std_m=0.01, heading_noise_std_rad=0.02)
    np.testing.assert_array_equal(
        pose_fix(pose, noise, params), oracle.pose_fix(pose, noise, params)
    )


def _random_table(rng: np.random.Generator, n: int) -> LinkTable:
    return LinkTable(
        latency_ms=rng.uniform(0.0, 20.0, (n, n)),
        jitter_ms=rng.uniform(0.0, 25.0, (n, n)),
        loss=rng.uniform(0.0, 0.5, (n, n)),
        burst=rng.random((n, n)) < 0.5,
        good_to_bad=rng.uniform(0.0, 0.3, (n, n)),
        bad_to_good=rng.uniform(0.0, 0.6, (n, n)),
        loss_in_good=rng.uniform(0.0, 0.1, (n, n)),
        loss_in_bad=rng.uniform(0.5, 1.0, (n, n)),
        cut=rng.random((n, n)) < 0.2,
        range_m=2.0,
    )


@pytest.mark.parametrize(
    "links", [PROFILES["lab"], PROFILES["bursty"], LinkProfile(range_m=1.0, loss=0.2), "table"]
)
def test_link_kernels_equal_the_numpy_links(links: LinkProfile | str) -> None:
    rng = np.random.default_rng(4)
    n = 5
    profile = _random_table(rng, n).rows(np.array([0, 2, 3])) if links == "table" else links
    bad = rng.random((4, 3, n)) < 0.5
    length_m = rng.uniform(0.0, 3.0, (4, 3, n))
    got = draw_links(profile, bad, length_m, np.random.default_rng(9))
    want = oracle.draw_links(profile, bad, length_m, np.random.default_rng(9))
    np.testing.assert_array_equal(got.delivered, want.delivered)
    np.testing.assert_array_equal(got.delay_s, np.broadcast_to(want.delay_s, got.delay_s.shape))
    np.testing.assert_array_equal(got.in_bad_state, want.in_bad_state)
    assert got.in_bad_state.shape == want.in_bad_state.shape


def _accumulators(batch: tuple[int, ...]) -> tuple[MetricsAccumulator, oracle.MetricsOracle]:
    layout = FormationLayout(
        names=("a", "b", "c", "d"),
        leader_index=0,
        slot_distance_m=np.array([0.0, 1.2, 1.2, 1.7]),
        slot_angle_rad=np.array([0.0, 2.5, -2.5, np.pi]),
    )
    centres, radii = np.array([[1.0, 0.5], [-2.0, 1.0]]), np.array([0.3, 0.5])
    config = MetricsConfig(steady_state_start_s=0.3, nominal_hold_s=0.2)
    return (
        MetricsAccumulator(batch, layout, centres, radii, config),
        oracle.MetricsOracle(batch, layout, centres, radii, config),
    )


@pytest.mark.parametrize("batch", [(), (3,)])
def test_metrics_kernel_equals_the_numpy_update(batch: tuple[int, ...]) -> None:
    rng = np.random.default_rng(5)
    compiled, numpy_form = _accumulators(batch)
    for k in range(60):
        t_s = 0.05 * k
        pose = rng.normal(0.0, 1.0, batch + (4, 3))
        pose[..., 2] = rng.uniform(-7.0, 7.0, batch + (4,))
        trajectory = rng.normal(0.0, 1.0, 3)
        contacts = None if k % 3 == 0 else rng.random(batch + (4, 6)) < 0.3
        if k == 30:
            for accumulator in (compiled, numpy_form):
                accumulator.set_leader(2, 1, t_s)
        errors = compiled.update(t_s, pose, trajectory, contacts)
        np.testing.assert_allclose(
            errors, numpy_form.update(t_s, pose, trajectory, contacts), rtol=0, atol=1e-12
        )
    for name in MetricsAccumulator.ARRAY_FIELDS:
        np.testing.assert_allclose(
            getattr(compiled, name), getattr(numpy_form, name), rtol=1e-12, atol=0, err_msg=name
        )
    assert np.all(compiled.collisions > 0)
    assert compiled.summaries() == numpy_form.summaries()

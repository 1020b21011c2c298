"""Taguchi L25(5^6) design: array, orthogonality, SNR, main effects, Table 1 levels."""

from collections.abc import Mapping

import numpy as np
import pytest

from services.tuner.benchmark_functions import sphere
from services.tuner.ofa import make_ofa_trial, ofa_parameters_from_design
from services.tuner.taguchi import (
    TaguchiFactor,
    chosen_levels,
    is_orthogonal_array,
    l25_orthogonal_array,
    response_table,
    smaller_the_better_snr,
    table1_factors,
    taguchi_design,
)


def test_l25_has_25_rows_six_columns_and_levels_0_to_4() -> None:
    array = l25_orthogonal_array()
    assert array.shape == (25, 6)
    for column in array.T:
        assert sorted(np.unique(column).tolist()) == [0, 1, 2, 3, 4]
        assert np.all(np.bincount(column, minlength=5) == 5)


def test_every_pair_of_l25_columns_holds_each_level_pair_exactly_once() -> None:
    array = l25_orthogonal_array()
    for first in range(6):
        for second in range(first + 1, 6):
            pairs = {
                (int(a), int(b)) for a, b in zip(array[:, first], array[:, second], strict=True)
            }
            assert len(pairs) == 25
    assert is_orthogonal_array(array)


def test_orthogonality_checker_rejects_a_broken_array() -> None:
    broken = l25_orthogonal_array()
    broken[3, 4] = (broken[3, 4] + 1) % 5
    assert not is_orthogonal_array(broken)


def test_orthogonality_checker_rejects_repeated_columns_and_bad_levels() -> None:
    array = l25_orthogonal_array()
    repeated = array.copy()
    repeated[:, 5] = repeated[:, 2]
    assert not is_orthogonal_array(repeated)
    out_of_range = array.copy()
    out_of_range[0, 0] = 5
    assert not is_orthogonal_array(out_of_range)
    assert not is_orthogonal_array(array[:24])


def test_smaller_the_better_snr_matches_hand_computed_values() -> None:
    assert smaller_the_better_snr(np.array([1.0, 1.0])) == pytest.approx(0.0)
    assert smaller_the_better_snr(np.array([0.1])) == pytest.approx(20.0)
    # mean(y^2) = (1 + 9) / 2 = 5 -> -10 log10(5) = -6.9897 dB
    assert smaller_the_better_snr(np.array([1.0, 3.0])) == pytest.approx(-6.98970004)
    # spread is penalised: same mean, larger variance, lower SNR
    assert smaller_the_better_snr(np.array([0.5, 1.5])) < smaller_the_better_snr(
        np.array([1.0, 1.0])
    )


def test_snr_refuses_all_zero_responses() -> None:
    with pytest.raises(ValueError):
        smaller_the_better_snr(np.zeros(3))


def test_response_table_is_the_mean_snr_per_factor_and_level() -> None:
    array = l25_orthogonal_array()
    snr_db = np.arange(25, dtype=np.float64)
    table = response_table(array, snr_db)
    assert table.shape == (6, 5)
    # column 0 is a = row // 5: level a holds rows 5a..5a+4, mean 5a + 2
    np.testing.assert_allclose(table[0], [2.0, 7.0, 12.0, 17.0, 22.0])
    # column 1 is b = row % 5: level b holds rows b, b+5, ..., mean b + 10
    np.testing.assert_allclose(table[1], [10.0, 11.0, 12.0, 13.0, 14.0])
    # every factor's levels average to the overall mean (balance)
    np.testing.assert_allclose(table.mean(axis=1), np.full(6, 12.0))


SYNTHETIC_TARGET_LEVELS = (3, 0, 4, 1, 2, 2)
SYNTHETIC_FACTORS = tuple(
    TaguchiFactor(name, (10.0, 20.0, 30.0, 40.0, 50.0))
    for name in ("f0", "f1", "f2", "f3", "f4", "f5")
)


def synthetic_trial(settings: Mapping[str, float], seed: int) -> float:
    """y = 10^(penalty / 20) with small seeded noise; its SNR is about -penalty dB."""
    penalty = sum(
        (settings[factor.name] / 10.0 - 1.0 - target) ** 2
        for factor, target in zip(SYNTHETIC_FACTORS, SYNTHETIC_TARGET_LEVELS, strict=True)
        if factor.name in settings
    )
    noise = np.random.default_rng(seed).normal(0.0, 0.02)
    return float(10.0 ** (penalty / 20.0) * (1.0 + noise))


def test_design_recovers_the_known_best_levels_of_a_synthetic_trial() -> None:
    result = taguchi_design(synthetic_trial, SYNTHETIC_FACTORS, 3, np.random.default_rng(5))
    assert result.responses.shape == (25, 3)
    assert tuple(result.chosen_levels.tolist()) == SYNTHETIC_TARGET_LEVELS
    assert tuple(chosen_levels(result.response_table).tolist()) == SYNTHETIC_TARGET_LEVELS
    assert result.chosen_settings == {
        "f0": 40.0,
        "f1": 10.0,
        "f2": 50.0,
        "f3": 20.0,
        "f4": 30.0,
        "f5": 30.0,
    }
    # the target combination has zero penalty: y ~= 1, SNR ~= 0 dB
    assert result.confirmation_snr_db == pytest.approx(0.0, abs=0.5)
    assert result.confirmation_snr_db > result.snr_db.max()
    # the additive model is exact for this trial, up to the noise
    assert result.predicted_snr_db == pytest.approx(0.0, abs=0.5)


def test_design_repeats_use_distinct_seeds_and_the_same_seed_reproduces_it() -> None:
    seen: list[tuple[dict[str, float], int]] = []

    def recording_trial(settings: Mapping[str, float], seed: int) -> float:
        seen.append((dict(settings), seed))
        return synthetic_trial(settings, seed)

    first = taguchi_design(recording_trial, SYNTHETIC_FACTORS[:4], 2, np.random.default_rng(9))
    assert len(seen) == 25 * 2 + 2
    design_seeds = {seed for _, seed in seen[:50]}
    confirmation_seeds = {seed for _, seed in seen[50:]}
    assert len(design_seeds) == 2
    assert len(confirmation_seeds) == 2
    assert design_seeds.isdisjoint(confirmation_seeds)
    assert all(settings == first.chosen_settings for settings, _ in seen[50:])

    second = taguchi_design(synthetic_trial, SYNTHETIC_FACTORS[:4], 2, np.random.default_rng(9))
    np.testing.assert_array_equal(first.responses, second.responses)
    assert first.confirmation_snr_db == second.confirmation_snr_db


def test_table1_factors_hold_the_paper_levels_with_delta_read_as_cooling() -> None:
    factors = {factor.name: factor.levels for factor in table1_factors()}
    assert factors["alpha0"] == (0.2, 0.5, 1.0, 2.0, 5.0)
    assert factors["beta0"] == (0.5, 1.0, 2.0, 3.0, 5.0)
    assert factors["gamma"] == (0.3, 0.5, 0.7, 0.9, 1.0)
    assert factors["delta"] == pytest.approx((0.999, 0.99, 0.98, 0.97, 0.96))
    assert factors["population_size"] == (100.0, 200.0, 300.0, 400.0, 500.0)
    assert factors["n_generations"] == (100.0, 150.0, 200.0, 250.0, 300.0)


def test_table1_delta_mapping_and_budget_scale_are_configurable() -> None:
    factors = {
        factor.name: factor.levels
        for factor in table1_factors(0.05, delta_mapping=lambda printed: 1.0 - printed / 100.0)
    }
    assert factors["delta"] == pytest.approx((0.99, 0.9, 0.8, 0.7, 0.6))
    assert factors["population_size"] == (5.0, 10.0, 15.0, 20.0, 25.0)
    assert factors["n_generations"] == (5.0, 8.0, 10.0, 13.0, 15.0)
    with pytest.raises(ValueError, match="collapses"):
        table1_factors(0.004)


def test_design_over_ofa_runs_and_yields_usable_parameters() -> None:
    trial = make_ofa_trial(sphere, 3)
    result = taguchi_design(trial, table1_factors(0.05), 1, np.random.default_rng(0))
    assert np.all(np.isfinite(result.snr_db))
    params = ofa_parameters_from_design(result)
    assert params.firefly.population_size == int(result.chosen_settings["population_size"])
    assert params.firefly.n_generations is None
    assert 0.0 < params.firefly.delta < 1.0

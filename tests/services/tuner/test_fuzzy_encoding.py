"""Decision vector of a fuzzy scheduler: decoding, the Table 2 default, the parameter file."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from robot_firmware.control.fuzzy import MAX_SETS, FuzzyRuleBase
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from services.tuner.fuzzy_encoding import (
    BLOCK_SIZE,
    COORDINATE_NAMES,
    DIMENSION,
    decode,
    encode_default,
    extents,
    rule_counts,
    set_counts,
    to_parameters,
)

unit = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
vectors = arrays(np.float64, (DIMENSION,), elements=unit)
batches = st.integers(min_value=1, max_value=6).flatmap(
    lambda p: arrays(np.float64, (p, DIMENSION), elements=unit)
)


@settings(max_examples=100, deadline=None)
@given(batches)
def test_decoding_gives_strictly_increasing_centres_and_two_to_seven_sets(x: np.ndarray) -> None:
    rule_base = decode(x)
    for centres, counts in (
        (rule_base.error_centres, rule_base.error_set_count),
        (rule_base.rate_centres, rule_base.rate_set_count),
    ):
        assert centres.shape == (x.shape[0], MAX_SETS)
        assert np.all((counts >= 2) & (counts <= MAX_SETS))
        for row, n in zip(centres, counts, strict=True):
            real = row[:n]
            assert np.all(np.isfinite(real))
            assert np.all(np.diff(real) > 0.0)
            assert real[0] == -real[-1]
            assert 0.25 <= real[-1] <= 4.0
            assert np.all(np.isposinf(row[n:]))
    np.testing.assert_array_equal(
        rule_base.rule_count, rule_base.error_set_count * rule_base.rate_set_count
    )
    np.testing.assert_array_equal(rule_counts(x), rule_base.rule_count)


@settings(max_examples=50, deadline=None)
@given(vectors)
def test_parameter_file_of_a_vector_is_valid_and_decodes_to_the_same_scheduler(
    x: np.ndarray,
) -> None:
    parameters = to_parameters(x)
    reloaded = FuzzyParameters.model_validate_json(parameters.model_dump_json())
    from_file = reloaded.rule_base()
    decoded = decode(x)
    np.testing.assert_array_equal(from_file.error_centres, decoded.error_centres[0])
    np.testing.assert_array_equal(from_file.rate_centres, decoded.rate_centres[0])
    np.testing.assert_array_equal(from_file.rule_outputs, decoded.rule_outputs[0])
    assert int(from_file.rule_count) == int(decoded.rule_count[0])


def test_default_vector_decodes_to_table2_with_even_centres() -> None:
    x = encode_default()
    assert x.shape == (DIMENSION,)
    assert np.all((x >= 0.0) & (x <= 1.0))
    decoded = decode(x)
    table2 = FuzzyRuleBase.table2()
    np.testing.assert_allclose(decoded.error_centres[0], table2.error_centres, atol=1e-15)
    np.testing.assert_allclose(decoded.rate_centres[0], table2.rate_centres, atol=1e-15)
    np.testing.assert_array_equal(decoded.rule_outputs[0], table2.rule_outputs)
    assert int(decoded.rule_count[0]) == 49


@pytest.mark.parametrize(("n_e", "n_d"), [(2, 7), (3, 5), (5, 3), (7, 2), (4, 6)])
def test_default_vector_at_other_set_counts_is_table2_restricted(n_e: int, n_d: int) -> None:
    decoded = decode(encode_default(n_e, n_d))
    table2 = FuzzyRuleBase.table2(n_e, n_d)
    np.testing.assert_allclose(decoded.error_centres[0], table2.error_centres, atol=1e-15)
    np.testing.assert_allclose(decoded.rate_centres[0], table2.rate_centres, atol=1e-15)
    np.testing.assert_array_equal(decoded.rule_outputs[0], table2.rule_outputs)


def test_set_count_bins_are_equal_and_cover_two_to_seven() -> None:
    u = np.array([0.0, 1 / 6 - 1e-9, 1 / 6, 0.5, 5 / 6 - 1e-9, 5 / 6, 1.0])
    np.testing.assert_array_equal(set_counts(u), [2, 2, 3, 5, 6, 7, 7])
    np.testing.assert_allclose(extents(np.array([0.0, 0.5, 1.0])), [0.25, 1.0, 4.0])


def test_gaps_past_the_set_count_do_not_change_the_scheduler() -> None:
    x = encode_default(3, 4)
    other = x.copy()
    other[2 + 2 : BLOCK_SIZE] = [0.0, 1.0, 0.3, 0.9]  # error gaps 3..6 (3 sets use 2)
    other[BLOCK_SIZE + 2 + 3 :] = [1.0, 0.0, 0.7]  # rate gaps 4..6 (4 sets use 3)
    first, second = decode(x), decode(other)
    np.testing.assert_array_equal(first.error_centres, second.error_centres)
    np.testing.assert_array_equal(first.rate_centres, second.rate_centres)
    other[2] = 0.9  # a used gap moves the middle centre off zero
    assert decode(other).error_centres[0, 1] != 0.0


def test_batch_decoding_matches_decoding_row_by_row() -> None:
    x = np.random.default_rng(3).random((5, DIMENSION))
    batch = decode(x)
    for p in range(5):
        one = decode(x[p])
        np.testing.assert_array_equal(batch.error_centres[p], one.error_centres[0])
        np.testing.assert_array_equal(batch.rate_centres[p], one.rate_centres[0])
        np.testing.assert_array_equal(batch.rule_outputs[p], one.rule_outputs[0])


def test_coordinate_names_cover_the_vector() -> None:
    assert len(COORDINATE_NAMES) == DIMENSION == 16
    assert COORDINATE_NAMES[0] == "error_sets"
    assert COORDINATE_NAMES[BLOCK_SIZE + 1] == "rate_extent"


@pytest.mark.parametrize(
    "bad",
    [np.zeros((2, DIMENSION - 1)), np.full((1, DIMENSION), 1.5), np.full(DIMENSION, np.nan)],
)
def test_bad_vectors_are_refused(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        decode(bad)


def test_encode_default_refuses_impossible_set_counts() -> None:
    with pytest.raises(ValueError):
        encode_default(1, 7)
    with pytest.raises(ValueError):
        encode_default(7, 8)

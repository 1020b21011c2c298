import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_firmware.control.fuzzy import (
    LABEL_OUTPUT,
    LABELS,
    TABLE2_RULES,
    FuzzyRuleBase,
    infer,
    table2_label_indices,
    table2_rule_outputs,
)
from tests.control.oracle import infer_full_product, memberships

# Table 2 of the paper, copied cell by cell from the printed table: rows e, columns ė.
PRINTED_TABLE2 = """
NB: PB PB PB PB PS ZO NS
NM: PB PB PM PM ZO NS NM
NS: PB PM PM PS NS NM NB
ZO: ZO ZO ZO ZO ZO ZO ZO
PS: NB NM NS PS PM PM PB
PM: NM NS ZO PM PB PB PB
PB: NS ZO PS PB PB PB PB
"""


def test_rule_table_as_data_matches_the_paper() -> None:
    rows = [line.split(":") for line in PRINTED_TABLE2.strip().splitlines()]
    assert [r[0] for r in rows] == list(LABELS)
    assert [tuple(r[1].split()) for r in rows] == list(TABLE2_RULES)
    values = table2_rule_outputs()
    assert values[0, 0] == LABEL_OUTPUT["PB"] == 1.0
    assert values[3, 5] == LABEL_OUTPUT["ZO"] == 0.0
    assert values[6, 0] == LABEL_OUTPUT["NS"]


def test_printed_table_breaks_point_symmetry_only_at_nm_ns() -> None:
    # ΔK(e, ė) = ΔK(-e, -ė) everywhere but the (NM, NS) / (PM, PS) pair (DESIGN.md §6).
    values = table2_rule_outputs()
    mirrored = values[::-1, ::-1]
    broken = {(LABELS[i], LABELS[j]) for i, j in zip(*np.nonzero(values != mirrored), strict=True)}
    assert broken == {("NM", "NS"), ("PM", "PS")}


@pytest.mark.parametrize(("n_e", "n_d"), [(7, 7), (5, 5), (3, 3), (5, 7), (3, 6)])
def test_output_at_zero_error_is_zo(n_e: int, n_d: int) -> None:
    rule_base = FuzzyRuleBase.table2(n_e, n_d)
    rates = np.linspace(-2.0, 2.0, 101)
    np.testing.assert_array_equal(infer(rule_base, np.zeros_like(rates), rates), 0.0)


def test_fast_path_equals_full_eq6_eq7_for_random_schedulers() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        n_e, n_d = rng.integers(2, 8, size=2)
        ce = np.sort(rng.uniform(-1, 1, n_e)) + np.arange(n_e) * 1e-3
        cd = np.sort(rng.uniform(-1, 1, n_d)) + np.arange(n_d) * 1e-3
        rules = rng.uniform(-1, 1, size=(n_e, n_d))
        base = FuzzyRuleBase.from_centres(ce, cd, rules)
        e = rng.uniform(-1.5, 1.5, 300)
        d = rng.uniform(-1.5, 1.5, 300)
        np.testing.assert_allclose(
            infer(base, e, d), infer_full_product(ce, cd, rules, e, d), atol=1e-12
        )


def test_batched_schedulers_with_different_set_counts() -> None:
    bases = [FuzzyRuleBase.table2(7, 7), FuzzyRuleBase.table2(3, 5), FuzzyRuleBase.table2(5, 2)]
    batch = FuzzyRuleBase.stack(bases).expand_dims((1,))
    e = np.random.default_rng(8).uniform(-1.2, 1.2, size=(3, 40))
    d = np.random.default_rng(9).uniform(-1.2, 1.2, size=(3, 40))
    batched = infer(batch, e, d)
    for i, base in enumerate(bases):
        np.testing.assert_allclose(batched[i], infer(base, e[i], d[i]), atol=1e-12)
    np.testing.assert_array_equal(FuzzyRuleBase.stack(bases).rule_count, [49, 15, 10])


@settings(max_examples=200, deadline=None)
@given(st.floats(-3, 3), st.lists(st.floats(-1, 1), min_size=2, max_size=7, unique=True))
def test_half_overlap_memberships_sum_to_one(x: float, raw: list[float]) -> None:
    centres = np.sort(np.asarray(raw))
    if np.any(np.diff(centres) < 1e-6):
        return
    mu = memberships(np.array([x]), centres)
    assert np.isclose(mu.sum(), 1.0)
    assert np.count_nonzero(mu > 1e-12) <= 2


def test_label_selection_for_smaller_schedulers() -> None:
    assert table2_label_indices(3) == (0, 3, 6)
    assert table2_label_indices(5) == (0, 1, 3, 5, 6)
    assert table2_label_indices(7) == tuple(range(7))
    with pytest.raises(ValueError):
        table2_label_indices(8)


def test_centres_must_increase() -> None:
    with pytest.raises(ValueError, match="increasing"):
        FuzzyRuleBase.from_centres([0.0, -0.5, 1.0], [-1.0, 1.0])

"""Fuzzy gain scheduler, eqs. 6-7 and Table 2.

Two inputs per controlled axis, the normalised tracking error e and its rate ė, each covered by
triangular membership functions that overlap by half: triangle i peaks at its centre c_i and
reaches zero at the neighbouring centres, so its half-widths are w_i⁻ = c_i - c_{i-1} and
w_i⁺ = c_{i+1} - c_i, and the memberships of any input sum to one (the outer sets are shoulders:
inputs beyond the outer centres are clipped to them).  Rule activation is the product of the two
memberships (eq. 7) and the output is the weighted average of the rule consequents (eq. 6).

With half overlap exactly two sets per input are active, so exactly four rules fire; the
compiled `infer_one` (numba) gathers those four instead of forming the full outer product.
tests/control/oracle.py keeps the literal eq. 6-7 form over all K rules to test it against.

Table 2 is kept as printed: rows are e, columns are ė, cells are the output ΔK, a singleton on
[-1, 1] (NB = -1 ... PB = +1).  Everywhere else the table is point symmetric,
ΔK(e, ė) = ΔK(-e, -ė); its cell (e=NM, ė=NS) = PM breaks that against (PM, PS) = PB.
DESIGN.md §6 keeps the printed value.

Parameters that an optimiser tunes (the paper's Firefly = {c_i, w_i, K}): the centres of each
input's sets (widths follow from them by the half-overlap rule) and the number of sets per
input, which fixes the rule count K = n_e·n_ė.  A scheduler with fewer than seven sets per
input uses the rows and columns of Table 2 picked by `table2_label_indices`.  Batches of
schedulers with different set counts are stored padded to seven sets (centres past the count
are +inf and never become active).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.kernels import njit
from robot_firmware.control.rows import as_rows, from_rows

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

LABELS: tuple[str, ...] = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
MAX_SETS = len(LABELS)
LABEL_OUTPUT: dict[str, float] = {
    label: value for label, value in zip(LABELS, np.linspace(-1.0, 1.0, MAX_SETS), strict=True)
}

TABLE2_RULES: tuple[tuple[str, ...], ...] = (
    # ė:  NB    NM    NS    ZO    PS    PM    PB        e:
    ("PB", "PB", "PB", "PB", "PS", "ZO", "NS"),  # NB
    ("PB", "PB", "PM", "PM", "ZO", "NS", "NM"),  # NM
    ("PB", "PM", "PM", "PS", "NS", "NM", "NB"),  # NS
    ("ZO", "ZO", "ZO", "ZO", "ZO", "ZO", "ZO"),  # ZO
    ("NB", "NM", "NS", "PS", "PM", "PM", "PB"),  # PS
    ("NM", "NS", "ZO", "PM", "PB", "PB", "PB"),  # PM
    ("NS", "ZO", "PS", "PB", "PB", "PB", "PB"),  # PB
)
"""Table 2 as printed: TABLE2_RULES[e_label][ė_label] is the consequent ΔK."""


def table2_label_indices(set_count: int) -> tuple[int, ...]:
    """Which of Table 2's seven labels a scheduler with `set_count` sets per input uses.

    The labels are spread evenly over NB..PB, rounding away from ZO, so that 3 sets use
    NB, ZO, PB and 5 sets use NB, NM, ZO, PM, PB.
    """
    if not 2 <= set_count <= MAX_SETS:
        raise ValueError(f"set count must be in 2..{MAX_SETS}, got {set_count}")
    positions = np.linspace(0.0, MAX_SETS - 1, set_count)
    centre = (MAX_SETS - 1) / 2.0
    rounded = np.where(positions < centre, np.floor(positions), np.ceil(positions))
    return tuple(int(i) for i in rounded)


def table2_rule_outputs(
    error_set_count: int = MAX_SETS, rate_set_count: int = MAX_SETS
) -> FloatArray:
    """Table 2 as a (7, 7) array of ΔK values, restricted to the given set counts and padded."""
    rows = table2_label_indices(error_set_count)
    cols = table2_label_indices(rate_set_count)
    out = np.zeros((MAX_SETS, MAX_SETS))
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            out[i, j] = LABEL_OUTPUT[TABLE2_RULES[r][c]]
    return out


def _padded_centres(centres: ArrayLike) -> FloatArray:
    c = np.asarray(centres, dtype=np.float64)
    n = c.shape[-1]
    if not 2 <= n <= MAX_SETS:
        raise ValueError(f"a fuzzy input needs 2..{MAX_SETS} sets, got {n}")
    if np.any(np.diff(c, axis=-1) <= 0.0):
        raise ValueError("membership centres must be strictly increasing")
    pad = np.full(c.shape[:-1] + (MAX_SETS - n,), np.inf)
    return np.concatenate([c, pad], axis=-1)


@dataclass(frozen=True)
class FuzzyRuleBase:
    """A (batch of) two-input fuzzy scheduler(s); array leading axes broadcast with the inputs.

    error_centres, rate_centres: (..., 7) normalised centres, +inf past the set count.
    error_set_count, rate_set_count: (...) number of sets per input.
    rule_outputs: (..., 7, 7) consequent ΔK, rows e, columns ė.
    """

    error_centres: FloatArray
    rate_centres: FloatArray
    error_set_count: IntArray
    rate_set_count: IntArray
    rule_outputs: FloatArray

    @property
    def rule_count(self) -> IntArray:
        """K in eq. 16: the number of rules of each scheduler."""
        return np.asarray(self.error_set_count * self.rate_set_count, dtype=np.int64)

    @staticmethod
    def from_centres(
        error_centres: ArrayLike,
        rate_centres: ArrayLike,
        rule_outputs: ArrayLike | None = None,
    ) -> FuzzyRuleBase:
        """One scheduler from its centres; the rules default to Table 2 at those set counts."""
        e = _padded_centres(error_centres)
        d = _padded_centres(rate_centres)
        n_e = int(np.shape(error_centres)[-1])
        n_d = int(np.shape(rate_centres)[-1])
        if rule_outputs is None:
            rules = table2_rule_outputs(n_e, n_d)
        else:
            given = np.asarray(rule_outputs, dtype=np.float64)
            if given.shape != (n_e, n_d):
                raise ValueError(f"rule table must be ({n_e}, {n_d}), got {given.shape}")
            rules = np.zeros((MAX_SETS, MAX_SETS))
            rules[:n_e, :n_d] = given
        return FuzzyRuleBase(
            error_centres=e,
            rate_centres=d,
            error_set_count=np.asarray(n_e, dtype=np.int64),
            rate_set_count=np.asarray(n_d, dtype=np.int64),
            rule_outputs=rules,
        )

    @staticmethod
    def table2(error_set_count: int = MAX_SETS, rate_set_count: int = MAX_SETS) -> FuzzyRuleBase:
        """The paper's scheduler with evenly spaced centres on [-1, 1]."""
        return FuzzyRuleBase.from_centres(
            np.linspace(-1.0, 1.0, error_set_count), np.linspace(-1.0, 1.0, rate_set_count)
        )

    @staticmethod
    def stack(rule_bases: list[FuzzyRuleBase]) -> FuzzyRuleBase:
        """A batch (leading axis) from single schedulers."""
        return FuzzyRuleBase(
            error_centres=np.stack([r.error_centres for r in rule_bases]),
            rate_centres=np.stack([r.rate_centres for r in rule_bases]),
            error_set_count=np.stack([r.error_set_count for r in rule_bases]),
            rate_set_count=np.stack([r.rate_set_count for r in rule_bases]),
            rule_outputs=np.stack([r.rule_outputs for r in rule_bases]),
        )

    def expand_dims(self, axes: tuple[int, ...]) -> FuzzyRuleBase:
        """Insert broadcast axes after the batch axes (e.g. robot and control-axis axes)."""

        def grow(a: NDArray[np.generic], trailing: int) -> NDArray[np.generic]:
            lead = a.ndim - trailing
            return np.expand_dims(a, tuple(lead + i for i in range(len(axes))))

        return FuzzyRuleBase(
            error_centres=np.asarray(grow(self.error_centres, 1), dtype=np.float64),
            rate_centres=np.asarray(grow(self.rate_centres, 1), dtype=np.float64),
            error_set_count=np.asarray(grow(self.error_set_count, 0), dtype=np.int64),
            rate_set_count=np.asarray(grow(self.rate_set_count, 0), dtype=np.int64),
            rule_outputs=np.asarray(grow(self.rule_outputs, 2), dtype=np.float64),
        )


@njit(cache=True)
def active_pair(x: float, centres: FloatArray, set_count: int) -> tuple[int, float]:
    """Index k of the left active set of one input and the membership of set k+1.

    The input is clipped to [c_0, c_{n-1}) (the outer sets are shoulders); set k then has
    membership 1 - μ_{k+1}, and every other set 0.
    """
    last = centres[set_count - 1]
    below_last = np.nextafter(last, -np.inf)
    xc = min(max(x, centres[0]), below_last)
    k = 0
    for j in range(1, set_count - 1):
        if centres[j] <= xc:
            k = j
    ck = centres[k]
    ck1 = centres[k + 1]
    return k, min(max((xc - ck) / (ck1 - ck), 0.0), 1.0)


@njit(cache=True)
def infer_one(
    error_centres: FloatArray,
    rate_centres: FloatArray,
    error_set_count: int,
    rate_set_count: int,
    rule_outputs: FloatArray,
    error_norm: float,
    rate_norm: float,
) -> float:
    """ΔK of one scheduler for one normalised input pair (eqs. 6-7), from the four rules that
    fire; their activations (eq. 7, products of memberships) sum to one, so eq. 6's denominator
    is 1."""
    ke, me = active_pair(error_norm, error_centres, error_set_count)
    kd, md = active_pair(rate_norm, rate_centres, rate_set_count)
    le = 1.0 - me
    ld = 1.0 - md
    return le * (ld * rule_outputs[ke, kd] + md * rule_outputs[ke, kd + 1]) + me * (
        ld * rule_outputs[ke + 1, kd] + md * rule_outputs[ke + 1, kd + 1]
    )


@njit(cache=True)
def _infer_rows(
    error_centres: FloatArray,
    rate_centres: FloatArray,
    error_set_count: IntArray,
    rate_set_count: IntArray,
    rule_outputs: FloatArray,
    error_norm: FloatArray,
    rate_norm: FloatArray,
) -> FloatArray:
    out = np.empty(error_norm.shape[0])
    for i in range(error_norm.shape[0]):
        out[i] = infer_one(
            error_centres[i], rate_centres[i], error_set_count[i], rate_set_count[i],
            rule_outputs[i], error_norm[i], rate_norm[i],
        )  # fmt: skip
    return out


def infer(rule_base: FuzzyRuleBase, error_norm: ArrayLike, rate_norm: ArrayLike) -> FloatArray:
    """ΔK for normalised inputs (eqs. 6-7); the rule base's batch axes broadcast with theirs."""
    batch, rows = as_rows(
        (rule_base.error_centres, 1, np.float64),
        (rule_base.rate_centres, 1, np.float64),
        (rule_base.error_set_count, 0, np.int64),
        (rule_base.rate_set_count, 0, np.int64),
        (rule_base.rule_outputs, 2, np.float64),
        (error_norm, 0, np.float64),
        (rate_norm, 0, np.float64),
    )
    return from_rows(_infer_rows(*rows), batch)

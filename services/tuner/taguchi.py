"""Taguchi parameter design of the OFA: L25(5^6) array, SNR and main effects (Table 1).

The paper picks the six FA parameters (alpha0, beta0, gamma, delta, P, N_fa),
each at five levels (Table 1), with an L25(5^6) orthogonal array and the
smaller-the-better signal-to-noise ratio.

* Orthogonal array: the 25 rows are the pairs (a, b) in Z5 x Z5, and the six
  columns are a, b and (b + k a) mod 5 for k = 1..4. Any two columns hold each
  of the 25 level pairs exactly once, so every level of one factor is tried
  with every level of any other factor equally often.
* SNR, smaller the better: eta = -10 log10(mean(y^2)) over the repeated runs of
  a trial, in dB; higher is better. It rewards a low response and a low spread.
* Main effects (response table): the mean SNR of the five trials that ran each
  factor at each level. Thanks to orthogonality the other factors are balanced
  in each such mean, so the level with the highest mean SNR is the chosen one.
* Confirmation: the chosen combination is usually not one of the 25 rows; it is
  run again (with fresh seeds) and its SNR reported next to the additive model's
  prediction, mean SNR + sum over factors of (chosen level's mean - mean SNR).

Table 1 prints delta in {1, 10, 20, 30, 40}, which contradicts 0 < delta < 1 in
eq. 4; DESIGN §6 reads it as delta = 1 - level / 1000 (see
:func:`delta_from_printed_level`), and :func:`table1_factors` takes the mapping
as an argument. With Table 1's P in {100..500} and N_fa in {100..300}, and a
trial spending P (N_fa + 1) evaluations, one pass over the 25 trials costs
about 1.5 million evaluations per repeat. ``budget_scale`` shrinks P and N_fa
(0.05 gives P in {5..25} and N_fa in {5..15}, about 4,000 evaluations per
repeat) so that a design on an expensive objective finishes in minutes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from services.tuner.evaluation import FloatArray, IntArray

N_LEVELS = 5
N_COLUMNS = 6

TrialFunction = Callable[[Mapping[str, float], int], float]
"""Runs one trial at the given settings with the given seed; returns y, smaller is better."""


def l25_orthogonal_array() -> IntArray:
    """The L25(5^6) array, shape (25, 6), levels 0..4: columns a, b, (b + k a) mod 5, k = 1..4."""
    a, b = np.divmod(np.arange(N_LEVELS * N_LEVELS, dtype=np.int64), N_LEVELS)
    columns = [a, b] + [(b + k * a) % N_LEVELS for k in range(1, N_LEVELS)]
    array: IntArray = np.stack(columns, axis=1)
    return array


def is_orthogonal_array(array: IntArray, n_levels: int = N_LEVELS) -> bool:
    """True when every pair of columns holds each level pair equally often.

    Levels must lie in 0..n_levels-1; in L25 each of the 25 pairs appears exactly once.
    """
    if not np.issubdtype(array.dtype, np.integer):
        return False
    if array.ndim != 2 or array.shape[0] % (n_levels * n_levels) != 0:
        return False
    if np.any(array < 0) or np.any(array >= n_levels):
        return False
    expected_count = array.shape[0] // (n_levels * n_levels)
    n_columns = array.shape[1]
    for first in range(n_columns):
        for second in range(first + 1, n_columns):
            pair_codes = array[:, first] * n_levels + array[:, second]
            counts = np.bincount(pair_codes, minlength=n_levels * n_levels)
            if np.any(counts != expected_count):
                return False
    return True


def smaller_the_better_snr(responses: FloatArray) -> float:
    """eta = -10 log10(mean(y^2)) in dB over the repeats in ``responses``."""
    responses = np.asarray(responses, dtype=np.float64)
    if responses.size == 0:
        raise ValueError("SNR needs at least one response")
    mean_square = float(np.mean(responses**2))
    if not math.isfinite(mean_square) or mean_square <= 0.0:
        raise ValueError(f"SNR needs finite responses, not all zero; mean square {mean_square}")
    return -10.0 * math.log10(mean_square)


def response_table(array: IntArray, snr_db: FloatArray) -> FloatArray:
    """Main effects: mean SNR per factor (row) and level (column), shape (n_columns, 5)."""
    if snr_db.shape != (array.shape[0],):
        raise ValueError(f"need one SNR per trial ({array.shape[0]}), got shape {snr_db.shape}")
    table = np.empty((array.shape[1], N_LEVELS), dtype=np.float64)
    for factor in range(array.shape[1]):
        for level in range(N_LEVELS):
            table[factor, level] = np.mean(snr_db[array[:, factor] == level])
    return table


def chosen_levels(table: FloatArray) -> IntArray:
    """Level with the highest mean SNR for each factor (first one on a tie)."""
    levels: IntArray = np.argmax(table, axis=1).astype(np.int64)
    return levels


@dataclass(frozen=True)
class TaguchiFactor:
    """A control factor: its name (the trial's settings key) and its five level values."""

    name: str
    levels: tuple[float, float, float, float, float]

    def __post_init__(self) -> None:
        if len(self.levels) != N_LEVELS:
            raise ValueError(f"factor {self.name} needs {N_LEVELS} levels, got {len(self.levels)}")
        if len(set(self.levels)) != N_LEVELS:
            raise ValueError(f"factor {self.name} has repeated levels {self.levels}")


def delta_from_printed_level(printed_level: float) -> float:
    """Table 1's printed delta level to a cooling factor in (0, 1): 1 - level / 1000."""
    return 1.0 - printed_level / 1000.0


TABLE1_PRINTED_DELTA_LEVELS = (1.0, 10.0, 20.0, 30.0, 40.0)


def _scaled_count_levels(
    name: str, levels: Sequence[int], budget_scale: float, minimum: int
) -> tuple[float, float, float, float, float]:
    scaled = tuple(float(max(minimum, math.floor(level * budget_scale + 0.5))) for level in levels)
    if len(set(scaled)) != N_LEVELS:
        raise ValueError(
            f"budget_scale={budget_scale} collapses the levels of {name} to {scaled}; "
            "use a larger scale"
        )
    return scaled[0], scaled[1], scaled[2], scaled[3], scaled[4]


def table1_factors(
    budget_scale: float = 1.0,
    delta_mapping: Callable[[float], float] = delta_from_printed_level,
) -> tuple[TaguchiFactor, ...]:
    """Table 1's six OFA factors, named like :class:`~services.tuner.firefly.FireflyParameters`.

    ``budget_scale`` multiplies the population sizes (P) and generation counts
    (N_fa), rounded half up, with at least 2 fireflies and 1 generation; a scale
    that makes two levels equal is refused. ``delta_mapping`` turns the printed
    delta levels into cooling factors (default 1 - level / 1000).
    """
    if budget_scale <= 0.0:
        raise ValueError(f"budget_scale must be positive, got {budget_scale}")
    d1, d2, d3, d4, d5 = (delta_mapping(level) for level in TABLE1_PRINTED_DELTA_LEVELS)
    return (
        TaguchiFactor("alpha0", (0.2, 0.5, 1.0, 2.0, 5.0)),
        TaguchiFactor("beta0", (0.5, 1.0, 2.0, 3.0, 5.0)),
        TaguchiFactor("gamma", (0.3, 0.5, 0.7, 0.9, 1.0)),
        TaguchiFactor("delta", (d1, d2, d3, d4, d5)),
        TaguchiFactor(
            "population_size",
            _scaled_count_levels("population_size", (100, 200, 300, 400, 500), budget_scale, 2),
        ),
        TaguchiFactor(
            "n_generations",
            _scaled_count_levels("n_generations", (100, 150, 200, 250, 300), budget_scale, 1),
        ),
    )


@dataclass(frozen=True)
class TaguchiResult:
    """Outcome of a Taguchi design: responses, SNRs, main effects, choice and confirmation."""

    factors: tuple[TaguchiFactor, ...]
    array: IntArray
    responses: FloatArray
    snr_db: FloatArray
    response_table: FloatArray
    chosen_levels: IntArray
    predicted_snr_db: float
    confirmation_responses: FloatArray
    confirmation_snr_db: float

    @property
    def chosen_settings(self) -> dict[str, float]:
        """Factor name to the value of its chosen level."""
        return {
            factor.name: factor.levels[int(level)]
            for factor, level in zip(self.factors, self.chosen_levels, strict=True)
        }


def _settings_of_row(factors: Sequence[TaguchiFactor], row: IntArray) -> dict[str, float]:
    return {
        factor.name: factor.levels[int(level)] for factor, level in zip(factors, row, strict=True)
    }


def _seeds(rng: np.random.Generator, count: int) -> list[int]:
    return [int(seed) for seed in rng.integers(0, 2**63 - 1, size=count)]


def taguchi_design(
    run_trial: TrialFunction,
    factors: Sequence[TaguchiFactor],
    repeats: int,
    rng: np.random.Generator,
) -> TaguchiResult:
    """Run the 25 trials of the L25 design, each ``repeats`` times, and confirm the choice.

    Factor k is assigned to column k of the array (at most six factors). Every
    trial uses the same ``repeats`` seeds (common random numbers), so level
    comparisons are not blurred by seed luck; the confirmation run uses
    ``repeats`` fresh seeds. All seeds come from ``rng``.
    """
    if not 1 <= len(factors) <= N_COLUMNS:
        raise ValueError(f"L25 holds 1 to {N_COLUMNS} factors, got {len(factors)}")
    if len({factor.name for factor in factors}) != len(factors):
        raise ValueError("factor names must be distinct")
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    array = l25_orthogonal_array()[:, : len(factors)]
    design_seeds = _seeds(rng, repeats)
    confirmation_seeds = _seeds(rng, repeats)

    responses = np.array(
        [
            [run_trial(_settings_of_row(factors, row), seed) for seed in design_seeds]
            for row in array
        ],
        dtype=np.float64,
    )
    snr_db = np.array([smaller_the_better_snr(trial) for trial in responses])
    table = response_table(array, snr_db)
    levels = chosen_levels(table)

    mean_snr_db = float(np.mean(snr_db))
    chosen_effects = table[np.arange(len(factors)), levels]
    predicted_snr_db = mean_snr_db + float(np.sum(chosen_effects - mean_snr_db))

    chosen = _settings_of_row(factors, levels)
    confirmation_responses = np.array(
        [run_trial(chosen, seed) for seed in confirmation_seeds], dtype=np.float64
    )
    return TaguchiResult(
        factors=tuple(factors),
        array=array,
        responses=responses,
        snr_db=snr_db,
        response_table=table,
        chosen_levels=levels,
        predicted_snr_db=predicted_snr_db,
        confirmation_responses=confirmation_responses,
        confirmation_snr_db=smaller_the_better_snr(confirmation_responses),
    )

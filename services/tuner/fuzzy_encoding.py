"""The decision vector of a candidate fuzzy scheduler: the firefly {c_i, w_i, K} of §II-B.

A candidate scheduler (eqs. 6-7, Table 2) is a point u of the unit box [0, 1]^16, the space
every optimiser of this package searches. The vector holds two blocks of eight coordinates, the
first for the error input e, the second for the error-rate input ė:

=====  ==============  ==========================================================================
index  name            decoding
=====  ==============  ==========================================================================
0, 8   ``*_sets``      set count n = min(2 + floor(6 u), 7): six equal bins, n in 2..7
1, 9   ``*_extent``    outer centre s = 2 ** (4 u - 2), log-uniform in [0.25, 4]; u = 0.5 gives 1
2-7,   ``*_gap_1..6``  relative gaps g_k = 0.125 + u_k in [0.125, 1.125] between neighbour centres;
10-15                  only the first n - 1 are used
=====  ==============  ==========================================================================

Decoding one input: the centres are the cumulative sums of its first n - 1 gaps, starting at 0,
mapped linearly onto [-s, s]:

    c_k = s (2 (g_1 + ... + g_k) / (g_1 + ... + g_{n-1}) - 1),   so c_0 = -s and c_{n-1} = s.

They are strictly increasing (every gap is positive and at most 9 times any other) and not
forced to be symmetric about zero: the ZO set of an odd count may move off zero. The widths
w_i follow from the centres, since neighbouring triangles overlap by half (eqs. 6-7 as
implemented in :mod:`robot_firmware.control.fuzzy`). The extent s is the input's scale
factor: the controller divides e and ė by its ``error_scale`` and ``error_rate_scale`` and clips
them to the outer centres, so outer centres at ±s make the outer sets saturate at s times those
scales. Folding the scale into the centres keeps a tuned scheduler a plain
:class:`~robot_firmware.control.fuzzy_parameters.FuzzyParameters` file, which robots load as
they are.

The rule consequents are not searched: they are Table 2 restricted to the decoded set counts
(:meth:`FuzzyRuleBase.from_centres`), so the rule count is K = n_e · n_ė, the N_i of eq. 16.
Coordinates of gaps past n - 1 do not affect the scheduler (the search space has neutral
directions whenever fewer than seven sets are chosen).

:func:`encode_default` gives a vector that decodes to Table 2 with evenly spaced centres on
[-1, 1]: seven sets, extent 1, equal gaps.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from robot_firmware.control.fuzzy import MAX_SETS, FuzzyRuleBase
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from services.tuner.evaluation import FloatArray, IntArray

MIN_SETS = 2
N_GAPS = MAX_SETS - 1
BLOCK_SIZE = 2 + N_GAPS
"""Coordinates per fuzzy input: set count, extent, six gaps."""
DIMENSION = 2 * BLOCK_SIZE
"""Length of a decision vector (16)."""

MIN_EXTENT = 0.25
MAX_EXTENT = 4.0
MIN_GAP = 0.125
"""Smallest relative gap; the largest is MIN_GAP + 1 (both exact in binary)."""

INPUT_NAMES = ("error", "rate")
COORDINATE_NAMES: tuple[str, ...] = tuple(
    name
    for prefix in INPUT_NAMES
    for name in (
        f"{prefix}_sets",
        f"{prefix}_extent",
        *(f"{prefix}_gap_{k}" for k in range(1, N_GAPS + 1)),
    )
)
"""Name of every coordinate, in vector order."""


def _as_batch(unit_vectors: ArrayLike) -> FloatArray:
    x = np.asarray(unit_vectors, dtype=np.float64)
    if x.ndim == 1:
        x = x[np.newaxis, :]
    if x.ndim != 2 or x.shape[1] != DIMENSION:
        raise ValueError(f"decision vectors must have shape (P, {DIMENSION}), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("decision vectors must be finite")
    if np.any(x < 0.0) or np.any(x > 1.0):
        raise ValueError("decision vectors must lie in [0, 1]")
    return x


def set_counts(unit_sets: FloatArray) -> IntArray:
    """n = min(2 + floor(6 u), 7) for each set-count coordinate u in [0, 1]."""
    bins = MAX_SETS - MIN_SETS + 1
    counts: IntArray = np.minimum(MIN_SETS + np.floor(bins * unit_sets).astype(np.int64), MAX_SETS)
    return counts


def extents(unit_extent: FloatArray) -> FloatArray:
    """s = 2 ** (4 u - 2): outer centre of an input, log-uniform on [0.25, 4]."""
    span = np.log2(MAX_EXTENT / MIN_EXTENT)
    scale: FloatArray = MIN_EXTENT * np.exp2(span * unit_extent)
    return scale


def _input_centres(block: FloatArray) -> tuple[IntArray, FloatArray]:
    """Set counts (P,) and padded centres (P, 7) of one input from its (P, 8) block."""
    count = set_counts(block[:, 0])
    extent = extents(block[:, 1])
    gaps = MIN_GAP + block[:, 2:]
    used = np.arange(N_GAPS)[np.newaxis, :] < (count - 1)[:, np.newaxis]
    cumulative = np.cumsum(np.where(used, gaps, 0.0), axis=1)
    total = cumulative[:, -1]
    fraction = np.concatenate(
        [np.zeros((block.shape[0], 1)), cumulative / total[:, np.newaxis]], axis=1
    )
    centres = extent[:, np.newaxis] * (2.0 * fraction - 1.0)
    real = np.arange(MAX_SETS)[np.newaxis, :] < count[:, np.newaxis]
    padded: FloatArray = np.where(real, centres, np.inf)
    return count, padded


def decode_centres(unit_vectors: ArrayLike) -> tuple[IntArray, FloatArray, IntArray, FloatArray]:
    """(n_e, error centres, n_ė, rate centres) of a batch; centres (P, 7), +inf past the count."""
    x = _as_batch(unit_vectors)
    n_e, error_centres = _input_centres(x[:, :BLOCK_SIZE])
    n_d, rate_centres = _input_centres(x[:, BLOCK_SIZE:])
    return n_e, error_centres, n_d, rate_centres


def decode(unit_vectors: ArrayLike) -> FuzzyRuleBase:
    """A batch of schedulers, leading axis P, from decision vectors (P, 16) in [0, 1].

    Centres are padded to seven with +inf, as :class:`FuzzyRuleBase` stores batches; the rules
    are Table 2 restricted to each candidate's set counts. A single vector (16,) gives a
    batch of one.
    """
    n_e, error_centres, n_d, rate_centres = decode_centres(unit_vectors)
    return FuzzyRuleBase.stack(
        [
            FuzzyRuleBase.from_centres(error_centres[p, : n_e[p]], rate_centres[p, : n_d[p]])
            for p in range(n_e.shape[0])
        ]
    )


def to_parameters(unit_vector: ArrayLike) -> FuzzyParameters:
    """The fuzzy parameter file (Table 2 rules, so no rule table) of one decision vector."""
    x = np.asarray(unit_vector, dtype=np.float64)
    if x.shape != (DIMENSION,):
        raise ValueError(f"one decision vector has shape ({DIMENSION},), got {x.shape}")
    n_e, error_centres, n_d, rate_centres = decode_centres(x)
    return FuzzyParameters(
        error_centres=[float(c) for c in error_centres[0, : n_e[0]]],
        rate_centres=[float(c) for c in rate_centres[0, : n_d[0]]],
    )


def rule_counts(unit_vectors: ArrayLike) -> IntArray:
    """K = n_e · n_ė of each candidate: the rules of one robot's scheduler (eq. 16)."""
    x = _as_batch(unit_vectors)
    counts: IntArray = set_counts(x[:, 0]) * set_counts(x[:, BLOCK_SIZE])
    return counts


def encode_default(error_set_count: int = MAX_SETS, rate_set_count: int = MAX_SETS) -> FloatArray:
    """A vector decoding to Table 2 at the given set counts with even centres on [-1, 1].

    Set-count coordinates sit in the middle of their bins, extents at 1 (u = 0.5) and all
    gaps equal (u = 0.5). With the default seven sets per input this is the paper's scheduler.
    """
    bins = MAX_SETS - MIN_SETS + 1
    block = np.full(BLOCK_SIZE, 0.5)
    vector = np.concatenate([block, block])
    for offset, count in ((0, error_set_count), (BLOCK_SIZE, rate_set_count)):
        if not MIN_SETS <= count <= MAX_SETS:
            raise ValueError(f"set count must be in {MIN_SETS}..{MAX_SETS}, got {count}")
        vector[offset] = (count - MIN_SETS + 0.5) / bins
    return vector

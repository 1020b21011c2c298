"""`as_rows`: arguments laid out as (R, *core) rows, against the plain numpy broadcast."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from robot_firmware.control.rows import as_rows, from_rows


def _reference(*arguments: tuple[Any, int, Any]) -> tuple[tuple[int, ...], list[np.ndarray]]:
    arrays = [np.asarray(a, dtype=dtype) for a, _, dtype in arguments]
    batch = np.broadcast_shapes(
        *(a.shape[: a.ndim - core] for a, (_, core, _) in zip(arrays, arguments, strict=True))
    )
    rows = []
    for a, (_, core, _) in zip(arrays, arguments, strict=True):
        core_shape = a.shape[a.ndim - core :]
        rows.append(np.broadcast_to(a, batch + core_shape).reshape((-1,) + core_shape))
    return batch, rows


RNG = np.random.default_rng(5)
CASES = {
    "one batch, as the world's state": (
        (RNG.normal(size=(6, 3)), 1, np.float64),
        (RNG.normal(size=(6, 4)), 1, np.float64),
        (RNG.normal(size=(6,)), 0, np.float64),
    ),
    "runs x robots": (
        (RNG.normal(size=(5, 3, 3)), 1, np.float64),
        (RNG.normal(size=(5, 3, 4)), 1, np.float64),
    ),
    "a shared argument broadcast over the batch": (
        (RNG.normal(size=(5, 3, 3)), 1, np.float64),
        (RNG.normal(size=(4,)), 1, np.float64),
        (2.5, 0, np.float64),
    ),
    "one robot": ((RNG.normal(size=(3,)), 1, np.float64), ([1, 2, 3, 4], 1, np.float64)),
    "dtypes converted": (
        (np.arange(12, dtype=np.int32).reshape(6, 2), 1, np.int64),
        ([[True], [False]] * 3, 1, np.bool_),
        (np.ones((6, 2), dtype=np.float32), 1, np.float64),
    ),
    "a batch of one broadcast up": (
        (RNG.normal(size=(1, 3)), 1, np.float64),
        (RNG.normal(size=(7, 4)), 1, np.float64),
    ),
}


@pytest.mark.parametrize("arguments", CASES.values(), ids=list(CASES))
def test_as_rows_equals_the_broadcast_and_reshape(arguments: tuple[Any, ...]) -> None:
    batch, rows = as_rows(*arguments)
    want_batch, want_rows = _reference(*arguments)
    assert batch == want_batch
    for row, want, (_, _, dtype) in zip(rows, want_rows, arguments, strict=True):
        assert row.dtype == np.dtype(dtype)
        assert row.shape == want.shape
        np.testing.assert_array_equal(row, want)


def test_rows_of_the_common_batch_are_the_arrays_themselves_and_go_back() -> None:
    pose = RNG.normal(size=(6, 3))
    batch, (rows,) = as_rows((pose, 1, np.float64))
    assert rows is pose  # no copy, no view: the kernels read the state in place
    assert from_rows(rows, batch).shape == (6, 3)


def test_arguments_that_do_not_broadcast_are_refused() -> None:
    with pytest.raises(ValueError):
        as_rows((np.zeros((5, 3)), 1, np.float64), (np.zeros((4, 3)), 1, np.float64))

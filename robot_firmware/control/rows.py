"""Array arguments laid out as the compiled kernels take them: one contiguous row per robot.

The kernels of this package loop over rows (R, ...) of float64, int64 or bool.  The array
forms of the equations accept any leading batch shape that broadcasts, as numpy functions do;
`as_rows` broadcasts the arguments' batch parts against each other and returns the batch shape
and each argument as (R, *core) rows, and `from_rows` gives an output its batch shape back.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray


def as_rows(
    *arguments: tuple[ArrayLike, int, DTypeLike],
) -> tuple[tuple[int, ...], list[NDArray[Any]]]:
    """(array, core dimensions, dtype) per argument -> batch shape and (R, *core) rows.

    Arrays of the wanted dtype are taken as they are, and when every argument has the same
    batch part (the world's and the batch simulator's state, every step) each is only
    reshaped: the broadcast is worked out only for arguments that differ."""
    arrays = []
    batches = []
    for a, core, dtype in arguments:
        wanted = _DTYPES.get(dtype) or np.dtype(dtype)
        if type(a) is not np.ndarray or a.dtype is not wanted:
            a = np.asarray(a, wanted)
        arrays.append(a)
        batches.append(a.shape[: a.ndim - core])
    batch = batches[0]
    if any(b != batch for b in batches):
        batch = np.broadcast_shapes(*batches)
    if len(batch) == 1:  # already rows wherever the batch is the common one
        rows = [
            a if b == batch else np.broadcast_to(a, batch + a.shape[a.ndim - core :])
            for a, b, (_, core, _) in zip(arrays, batches, arguments, strict=True)
        ]
        return batch, rows
    rows = []
    for a, b, (_, core, _) in zip(arrays, batches, arguments, strict=True):
        shape = a.shape[a.ndim - core :]
        rows.append((a if b == batch else np.broadcast_to(a, batch + shape)).reshape((-1,) + shape))
    return batch, rows


def rows_of(
    batch: tuple[int, ...], *arguments: tuple[ArrayLike, int, DTypeLike]
) -> list[NDArray[Any]]:
    """As `as_rows` for a known batch shape: arrays that already have it are only reshaped.

    One robot (batch ()) is the firmware's case, every tick: an array of the right dtype with
    only its core dimensions becomes a (1, *core) view with no other work."""
    rows = []
    single = batch == ()
    for a, core, dtype in arguments:
        wanted = _DTYPES.get(dtype) or np.dtype(dtype)
        if type(a) is np.ndarray and a.dtype is wanted:
            if single and a.ndim == core:
                rows.append(a[np.newaxis])
                continue
            array = a
        else:
            array = np.asarray(a, wanted)
        shape = array.shape[array.ndim - core :] if core else ()
        if array.shape[: array.ndim - core] != batch:
            array = np.broadcast_to(array, batch + shape)
        rows.append(array.reshape((-1,) + shape))
    return rows


_DTYPES: dict[Any, np.dtype[Any]] = {t: np.dtype(t) for t in (np.float64, np.int64, np.bool_)}


def from_rows(rows: NDArray[Any], batch: tuple[int, ...]) -> NDArray[Any]:
    """Rows (R, *core) back to batch + core."""
    return rows.reshape(batch + rows.shape[1:])

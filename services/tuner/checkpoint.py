"""Saving and restoring an optimiser's complete run state, so a run can resume.

A checkpoint holds everything the generation loop needs to continue exactly
where it stopped: the population and its costs, algorithm-specific arrays (PSO
velocities and personal bests, for example), the best candidate, the generation
and evaluation counters, the convergence history, and the random generator's
bit-generator state. Restoring all of it makes a resumed run produce the same
result, bit for bit, as one that was never interrupted.

The file is a NumPy ``.npz`` archive read without pickle. It is written to a
temporary file in the destination folder and then moved into place with
``os.replace``, so a crash while saving leaves the previous checkpoint intact.
A fingerprint (algorithm, dimension, budget, parameters) is stored with the
state; resuming with a different setup is refused.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from services.tuner.evaluation import FloatArray, IntArray
from swarm_config.atomic_files import PRIVATE_FILE_MODE, write_file_atomically

CHECKPOINT_FORMAT_VERSION = 1
_AUXILIARY_PREFIX = "auxiliary__"


class CheckpointMismatchError(ValueError):
    """The checkpoint on disk was written by a run with a different setup."""


class CheckpointDamagedError(ValueError):
    """The checkpoint on disk cannot be read: cut short, overwritten, or not a checkpoint."""

    @classmethod
    def at(cls, path: str | os.PathLike[str], problem: str) -> CheckpointDamagedError:
        """The error for the checkpoint at `path`, `problem` saying what is wrong with it."""
        return cls(
            f"{os.fspath(path)} is damaged ({problem}) and cannot be resumed: move it away to "
            "start that run over"
        )


@dataclass(frozen=True)
class RunCheckpoint:
    """Complete state of a population-based run after a finished generation."""

    fingerprint: str
    generation: int
    positions: FloatArray
    costs: FloatArray
    best_x: FloatArray
    best_cost: float
    n_evaluations: int
    history_n_evaluations: IntArray
    history_best_cost: FloatArray
    rng_state: Mapping[str, Any]
    auxiliary: Mapping[str, FloatArray] = field(default_factory=dict)


def json_compatible(value: object) -> object:
    """``json.dumps`` fallback for the NumPy values found in generator states."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer):
        return int(value)
    raise TypeError(f"cannot store {type(value).__name__} in a checkpoint")


def save_checkpoint(path: str | os.PathLike[str], checkpoint: RunCheckpoint) -> None:
    """Write ``checkpoint`` to ``path`` durably in one rename (swarm_config/atomic_files.py);
    FileWriteError, the previous checkpoint untouched, when it cannot be written."""
    destination = Path(path)
    arrays: dict[str, Any] = {
        "format_version": np.array(CHECKPOINT_FORMAT_VERSION),
        "fingerprint": np.array(checkpoint.fingerprint),
        "generation": np.array(checkpoint.generation, dtype=np.int64),
        "positions": checkpoint.positions,
        "costs": checkpoint.costs,
        "best_x": checkpoint.best_x,
        "best_cost": np.array(checkpoint.best_cost, dtype=np.float64),
        "n_evaluations": np.array(checkpoint.n_evaluations, dtype=np.int64),
        "history_n_evaluations": checkpoint.history_n_evaluations,
        "history_best_cost": checkpoint.history_best_cost,
        "rng_state": np.array(json.dumps(dict(checkpoint.rng_state), default=json_compatible)),
    }
    for name, values in checkpoint.auxiliary.items():
        arrays[_AUXILIARY_PREFIX + name] = values
    archive = io.BytesIO()
    np.savez(archive, **arrays)
    write_file_atomically(destination, archive.getvalue(), mode=PRIVATE_FILE_MODE)


def load_checkpoint(path: str | os.PathLike[str]) -> RunCheckpoint:
    """Read a checkpoint written by :func:`save_checkpoint`.

    CheckpointMismatchError for another format; CheckpointDamagedError for a file that is not
    a whole checkpoint (cut short, overwritten, not an archive, a field missing).
    """
    try:
        return _read_checkpoint(path)
    except (CheckpointMismatchError, CheckpointDamagedError):
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, RecursionError) as exc:
        # ValueError: also numpy's refusal of an object array, which a checkpoint never holds.
        raise CheckpointDamagedError.at(path, type(exc).__name__) from None


BIT_GENERATORS: dict[str, type[np.random.BitGenerator]] = {
    "PCG64": np.random.PCG64,
    "PCG64DXSM": np.random.PCG64DXSM,
    "MT19937": np.random.MT19937,
    "Philox": np.random.Philox,
    "SFC64": np.random.SFC64,
}
"""NumPy's bit generators by the name their state carries."""


def rng_state_problem(state: object) -> str | None:
    """Why `state` cannot be given to the bit generator it names, else None."""
    if not isinstance(state, Mapping):
        return "rng_state: not a generator state"
    kind = BIT_GENERATORS.get(str(state.get("bit_generator")))
    if kind is None:
        return f"rng_state: no bit generator {str(state.get('bit_generator'))[:40]!r}"
    try:
        kind(0).state = dict(state)
    except (TypeError, ValueError, KeyError, OverflowError) as exc:
        return f"rng_state: not a {kind.__name__} state ({type(exc).__name__})"
    return None


def _positive_costs(values: FloatArray) -> bool:
    """Every value finite and above 0, as every objective's cost is (evaluation.py)."""
    return bool(np.all(np.isfinite(values) & (values > 0.0)))


def checkpoint_problem(checkpoint: RunCheckpoint, dim: int, budget: int) -> str | None:
    """What makes a readable checkpoint unusable for a run over [0, 1]^`dim` with `budget`
    evaluations, else None: arrays of other shapes, values that no run writes (outside the
    unit cube, costs that are not finite and positive), counters outside the budget or out of
    step with the history, a generator state its generator refuses.  The archive's own checks
    do not see a file whose fields were changed one by one, and resuming from one crashed the
    tuner or wrote results from nonsense."""
    positions = checkpoint.positions
    if positions.ndim != 2 or positions.shape[0] < 1 or positions.shape[1] != dim:
        return f"positions: shape {positions.shape}, the run needs (population, {dim})"
    count = positions.shape[0]
    if not np.all((positions >= 0.0) & (positions <= 1.0)):
        return "positions: values outside [0, 1] (or NaN)"
    if checkpoint.costs.shape != (count,) or not _positive_costs(checkpoint.costs):
        return (
            f"costs: shape {checkpoint.costs.shape} or values not finite and above 0, the run "
            f"needs ({count},) costs"
        )
    best_x = checkpoint.best_x
    if best_x.shape != (dim,) or not np.all((best_x >= 0.0) & (best_x <= 1.0)):
        return f"best_x: not {dim} values in [0, 1]"
    if not (math.isfinite(checkpoint.best_cost) and checkpoint.best_cost > 0.0):
        return f"best_cost: {checkpoint.best_cost}, not a finite cost above 0"
    if not 0 <= checkpoint.n_evaluations <= budget:
        return f"n_evaluations: {checkpoint.n_evaluations}, outside [0, {budget}]"
    if checkpoint.generation < 0:
        return f"generation: {checkpoint.generation}"
    history = checkpoint.history_n_evaluations
    if history.ndim != 1 or checkpoint.history_best_cost.shape != history.shape:
        return "history: its two columns differ in length"
    if history.shape[0] != checkpoint.generation + 1:
        return (
            f"generation: {checkpoint.generation}, but the history holds {history.shape[0]} "
            "generations"
        )
    if not _positive_costs(checkpoint.history_best_cost):
        return "history_best_cost: values not finite and above 0"
    if (
        np.any(history < 0)
        or np.any(np.diff(history) < 0)
        or history[-1] > checkpoint.n_evaluations
    ):
        return (
            "history_n_evaluations: not counts rising from 0 to n_evaluations "
            f"({checkpoint.n_evaluations})"
        )
    for name, values in checkpoint.auxiliary.items():
        if values.shape not in ((count,), (count, dim)) or np.isnan(values).any():
            return f"{name}: shape {values.shape} or NaN, the population has {count} members"
    return rng_state_problem(checkpoint.rng_state)


def _number_field(path: str | os.PathLike[str], archive: Any, name: str, kinds: str) -> int | float:
    """The archive's field `name` as one number whose dtype kind is in `kinds`, else
    CheckpointDamagedError naming the field (int() and float() of an array or a complex number
    raised TypeError, which went up as a traceback)."""
    value = np.asarray(archive[name])
    if value.shape != () or value.dtype.kind not in kinds:
        what = "integer" if kinds == "iu" else "number"
        raise CheckpointDamagedError.at(
            path, f"{name}: shape {value.shape}, dtype {value.dtype}, not one {what}"
        )
    number: int | float = value.item()
    return number


def _read_checkpoint(path: str | os.PathLike[str]) -> RunCheckpoint:
    # Opened here, not by np.load, which leaves its file open when the archive is not one.
    with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
        version = int(_number_field(path, archive, "format_version", "iu"))
        if version != CHECKPOINT_FORMAT_VERSION:
            raise CheckpointMismatchError(
                f"checkpoint format {version} is not supported "
                f"(expected {CHECKPOINT_FORMAT_VERSION})"
            )
        auxiliary = {
            key.removeprefix(_AUXILIARY_PREFIX): np.array(archive[key])
            for key in archive.files
            if key.startswith(_AUXILIARY_PREFIX)
        }
        return RunCheckpoint(
            fingerprint=str(archive["fingerprint"]),
            generation=int(_number_field(path, archive, "generation", "iu")),
            positions=np.array(archive["positions"], dtype=np.float64),
            costs=np.array(archive["costs"], dtype=np.float64),
            best_x=np.array(archive["best_x"], dtype=np.float64),
            best_cost=float(_number_field(path, archive, "best_cost", "iuf")),
            n_evaluations=int(_number_field(path, archive, "n_evaluations", "iu")),
            history_n_evaluations=np.array(archive["history_n_evaluations"], dtype=np.int64),
            history_best_cost=np.array(archive["history_best_cost"], dtype=np.float64),
            rng_state=json.loads(str(archive["rng_state"])),
            auxiliary=auxiliary,
        )

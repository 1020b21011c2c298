"""World checkpoints: the whole state of a running world in one self-checking file (DESIGN.md §7.1).

A checkpoint is one file, `world-<tick>.ckpt`, of two parts separated by a newline:

    header  one line of JSON: {"format": "swarm-world-checkpoint", "version": 1,
            "sha256": <hex digest of the body>, "length": <bytes of the body>}
    body    JSON (sorted keys, no NaN): the state; numpy arrays as
            {"dtype": "<f8", "shape": [...], "b64": <base64 of the little-endian bytes>},
            so floats come back bit for bit (NaN and infinity included)

No pickle: a file from disk is only ever parsed as JSON, and an array only as one of the
dtypes in `ARRAY_DTYPES`.  A file whose header does not parse, whose format or version is not
this one, whose body is shorter or longer than announced or whose digest differs (a truncated
or bit-flipped file) is refused with a `CheckpointError` naming the reason.

Files are written atomically and durably: a temporary file in the same directory, fsync,
rename over the final name, fsync of the directory.  A process killed mid-write leaves the
older checkpoints as they were.  `CheckpointStore` keeps the newest `keep` (two) and, when
asked for the latest, tries them newest first: a refused file is logged, renamed aside
(`*.refused`) and the previous one is used.  A checkpoint names its run (`run_id`, from the
world's credentials): a world removes those of any other run before it looks for one to resume
(`clear_other_runs`), so a new run in a used folder starts afresh.
"""

from __future__ import annotations

import base64
import hashlib
import json
import logging
import re
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from swarm_config.atomic_files import PRIVATE_FILE_MODE, write_file_atomically
from world.write_failures import WriteFailures

log = logging.getLogger("swarm.world.checkpoint")

CHECKPOINT_FORMAT = "swarm-world-checkpoint"
CHECKPOINT_VERSION = 1
CHECKPOINT_DIR_NAME = "checkpoints"
ARRAY_DTYPES = frozenset({"<f8", "<i8", "|b1"})
"""The only array element types a checkpoint may hold: float64, int64, bool."""
_NAME = re.compile(r"^world-(\d{12})\.ckpt$")


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used, and why."""


def encode_array(array: NDArray[Any]) -> dict[str, object]:
    """An array as JSON: its dtype, shape and little-endian bytes in base64."""
    a = np.asarray(array)
    dtype = a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype
    if dtype.str not in ARRAY_DTYPES:
        raise TypeError(f"arrays of {a.dtype} do not go into a checkpoint")
    data = np.ascontiguousarray(a, dtype=dtype).tobytes()
    return {"dtype": dtype.str, "shape": list(a.shape), "b64": base64.b64encode(data).decode()}


def decode_array(value: object) -> NDArray[Any]:
    """The array `encode_array` wrote; a malformed entry raises CheckpointError."""
    if not isinstance(value, dict) or set(value) != {"dtype", "shape", "b64"}:
        raise CheckpointError("an array entry is malformed")
    dtype, shape, b64 = value["dtype"], value["shape"], value["b64"]
    if dtype not in ARRAY_DTYPES:
        raise CheckpointError(f"array dtype {dtype!r} is not allowed")
    if not isinstance(shape, list) or not all(isinstance(s, int) and s >= 0 for s in shape):
        raise CheckpointError("an array shape is malformed")
    try:
        data = base64.b64decode(str(b64), validate=True)
        return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape).copy()
    except ValueError as exc:
        raise CheckpointError(f"an array's data is malformed: {exc}") from None


def encode_checkpoint(state: Mapping[str, object]) -> bytes:
    """The file's bytes for `state` (JSON-able values and `encode_array` entries)."""
    body = json.dumps(state, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()
    header = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "sha256": hashlib.sha256(body).hexdigest(),
        "length": len(body),
    }
    return json.dumps(header, sort_keys=True).encode() + b"\n" + body


def decode_checkpoint(raw: bytes) -> dict[str, Any]:
    """The state in a checkpoint file's bytes; raises CheckpointError with the reason."""
    head, newline, body = raw.partition(b"\n")
    if not newline:
        raise CheckpointError("no header line (truncated?)")
    try:
        header = json.loads(head)
    except (ValueError, RecursionError):
        raise CheckpointError("the header is not JSON") from None
    if not isinstance(header, dict) or header.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError("not a world checkpoint")
    if header.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"version {header.get('version')!r}, this world reads version {CHECKPOINT_VERSION}"
        )
    if header.get("length") != len(body):
        raise CheckpointError(
            f"body is {len(body)} bytes, the header announces {header.get('length')!r} (truncated?)"
        )
    if header.get("sha256") != hashlib.sha256(body).hexdigest():
        raise CheckpointError("checksum mismatch (corrupt)")
    try:
        state = json.loads(body)
    except (ValueError, RecursionError):
        raise CheckpointError("the body is not JSON") from None
    if not isinstance(state, dict):
        raise CheckpointError("the body is not a JSON object")
    return state


def write_bytes_atomically(path: Path, data: bytes) -> None:
    """Write `data` to `path` durably: temporary file, fsync, rename, fsync of the directory
    (swarm_config/atomic_files.py), private to the world's user.

    A reader (or a process restarted after a kill at any point) sees the old file or the new
    one, never part of one; FileWriteError when it cannot be written."""
    write_file_atomically(path, data, mode=PRIVATE_FILE_MODE)


@dataclass(frozen=True)
class LoadedCheckpoint:
    path: Path
    tick: int
    state: dict[str, Any]


class CheckpointStore:
    """A world's checkpoints in one directory (`<out>/checkpoints/`), the newest `keep` kept."""

    def __init__(self, directory: Path, keep: int = 2) -> None:
        if keep < 1:
            raise ValueError("keep at least one checkpoint")
        self.directory = directory
        self.keep = keep

    def paths(self) -> list[tuple[int, Path]]:
        """(tick, path) of every checkpoint file, newest first."""
        if not self.directory.is_dir():
            return []
        found = []
        for path in self.directory.iterdir():
            match = _NAME.match(path.name)
            if match is not None:
                found.append((int(match.group(1)), path))
        return sorted(found, reverse=True)

    def save(self, tick: int, state: Mapping[str, object]) -> Path:
        """Write the checkpoint of `tick`, then delete all but the newest `keep`."""
        return self.save_encoded(tick, encode_checkpoint(state))

    def save_encoded(self, tick: int, data: bytes) -> Path:
        path = self.directory / f"world-{tick:012d}.ckpt"
        write_bytes_atomically(path, data)
        for _tick, old in self.paths()[self.keep :]:
            old.unlink(missing_ok=True)
        return path

    def clear(self) -> int:
        """Remove every checkpoint (refused ones and a killed writer's temporary files too):
        the folder's next world starts afresh.  Returns how many checkpoints there were."""
        if not self.directory.is_dir():
            return 0
        found = len(self.paths())
        for pattern in ("world-*.ckpt", "world-*.ckpt.refused", ".world-*.ckpt.*"):
            for path in self.directory.glob(pattern):
                path.unlink(missing_ok=True)
        return found

    def clear_other_runs(self, run_id: str) -> int:
        """Remove the checkpoints of any run but `run_id` (a checkpoint names its run: the
        `run_id` of its world's credentials); returns how many.  One that cannot be read is
        left for `load_latest` to refuse."""
        removed = 0
        for _tick, path in self.paths():
            try:
                state = decode_checkpoint(path.read_bytes())
            except (CheckpointError, OSError):
                continue
            if state.get("run_id") != run_id:
                path.unlink(missing_ok=True)
                removed += 1
        return removed

    def load_latest(
        self, restore: Callable[[dict[str, Any]], None] | None = None
    ) -> LoadedCheckpoint | None:
        """The newest checkpoint that passes every check, and that `restore` (if given) takes
        without raising CheckpointError; refused ones are logged and set aside as
        `*.refused`.  None when there is none.  Temporary files a killed writer left behind
        are deleted."""
        if self.directory.is_dir():
            for leftover in self.directory.glob(".world-*.ckpt.*"):
                leftover.unlink(missing_ok=True)
        for tick, path in self.paths():
            try:
                state = decode_checkpoint(path.read_bytes())
                if restore is not None:
                    restore(state)
            except (CheckpointError, OSError) as exc:
                log.error("checkpoint %s refused: %s; trying the previous one", path.name, exc)
                path.replace(path.with_name(path.name + ".refused"))
                continue
            return LoadedCheckpoint(path=path, tick=tick, state=state)
        return None


class CheckpointWriter:
    """Encodes and writes checkpoints on a thread of its own, so that neither the encoding nor
    fsync holds up the world loop.

    `submit` hands over a state (JSON-able values only, which nobody changes afterwards) and
    returns at once; if the previous one is still being written, the newer replaces any that
    waits (only the newest matters)."""

    def __init__(self, store: CheckpointStore, write_failures: WriteFailures | None = None) -> None:
        self.store = store
        self.written = 0
        self.write_failures = write_failures or WriteFailures("checkpoint", log)
        self._pending: tuple[int, Mapping[str, object]] | None = None
        self._lock = threading.Lock()
        self._ready = threading.Condition(self._lock)
        self._closing = False
        self._busy = False
        self._thread = threading.Thread(target=self._run, name="checkpoint-writer", daemon=True)
        self._thread.start()

    def submit(self, tick: int, state: Mapping[str, object]) -> None:
        with self._lock:
            self._pending = (tick, state)
            self._ready.notify()

    def flush(self, timeout_s: float = 10.0) -> None:
        """Wait until every submitted checkpoint is on disk (or the time-out passes)."""
        with self._lock:
            self._ready.wait_for(lambda: self._pending is None and not self._busy, timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        self.flush(timeout_s)
        with self._lock:
            self._closing = True
            self._ready.notify_all()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._lock:
                self._ready.wait_for(lambda: self._pending is not None or self._closing)
                if self._pending is None:
                    return
                tick, state = self._pending
                self._pending = None
                self._busy = True
            try:
                self.store.save(tick, state)
                self.written += 1
                self.write_failures.succeeded()
            except OSError as exc:
                self.write_failures.failed(exc)
            finally:
                with self._lock:
                    self._busy = False
                    self._ready.notify_all()

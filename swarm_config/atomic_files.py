"""Files written whole or not at all: summaries, checkpoints, credentials, tuning results.

Every file the project writes for a user to keep goes through `write_file_atomically`: the bytes
go to a temporary file in the same folder, which is renamed over the target only once it is
complete (and, when `durable`, flushed to the disk with its folder).  A reader, or a process
restarted after a kill at any instant, finds the old file or the new one, never a part of one.

A write that fails (a full disk, a quota, a read-only file system, a folder that went away)
removes its temporary file, leaves the old file as it was, and raises `FileWriteError`, an
`OSError` whose message names the file: "cannot write runs/x/summary.json: No space left on
device".  The command line prints that one line; the world logs it and goes on stepping.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

PUBLIC_FILE_MODE = 0o644
"""A result for everyone on the machine to read (a summary, a figure)."""
PRIVATE_FILE_MODE = 0o600
"""A file only its owner may read (credentials, checkpoints)."""


class FileWriteError(OSError):
    """A file that could not be written; `filename` names it, `strerror` says why."""

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"


def write_file_atomically(
    path: Path, data: bytes, *, mode: int = PUBLIC_FILE_MODE, durable: bool = True
) -> None:
    """Replace `path` with `data` in one rename; the new file has `mode` from its first byte.

    durable=True also fsyncs the file and its folder, so the new file survives a power cut;
    durable=False leaves that to the page cache (it still survives a killed process), for
    files rewritten often while a run goes on.  A missing folder is made, with its parents.

    Raises FileWriteError when any step fails; the old file, if any, is untouched and no
    temporary file is left.
    """
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    except OSError as exc:
        raise FileWriteError(exc.errno, exc.strerror or str(exc), str(path)) from None
    try:
        with os.fdopen(descriptor, "wb") as handle:
            os.fchmod(handle.fileno(), mode)  # mkstemp makes it 0600; umask does not apply
            handle.write(data)
            handle.flush()
            if durable:
                os.fsync(handle.fileno())
        os.replace(temporary, path)
        if durable:
            folder = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(folder)
            finally:
                os.close(folder)
    except OSError as exc:
        Path(temporary).unlink(missing_ok=True)
        raise FileWriteError(exc.errno, exc.strerror or str(exc), str(path)) from None
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise

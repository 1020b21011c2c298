"""The folders the `swarm` commands write into: checked before any work starts.

`swarm sim --out`, `swarm up --out`, `swarm tune --out`, `swarm dashboard --out` and the DIR of
`swarm credentials` all name a folder that may not exist yet.  A path that cannot be one (a
file, a path under a file, a read-only or pseudo file system, a folder without write
permission, a sysfs folder that access(2) calls writable for root) used to surface as a
traceback from deep inside the run, in `swarm sim`'s case only after the whole simulation had
run.  `prepare_output_folder` creates the folder up front and says in one line, naming the
option, why it cannot.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

DEFAULT_FOLDER_MODE = 0o777
"""The mode `mkdir` is given (less the umask), as `Path.mkdir` gives by default."""


WRITE_PROBE_PREFIX = ".swarm-write-check-"
"""The name of the empty file made and removed in a folder to see that files can be made there."""


class OutputFolderError(ValueError):
    """An output folder that cannot be created or written; the message names the option."""


def prepare_output_folder(path: Path, option: str, *, mode: int = DEFAULT_FOLDER_MODE) -> Path:
    """Create `path` and its parents (new folders get `mode`), and check this process can
    write in it; returns `path`.

    Raises OutputFolderError, whose message starts with `option` and the path, when `path` is
    not a folder, cannot be created, or is not writable (access(2) says so, or a file cannot
    be made in it).
    """
    try:
        is_a_file = path.exists() and not path.is_dir()
    except OSError as exc:  # a name too long for the file system, a loop of links
        raise OutputFolderError(
            f"{option} {path}: cannot use the folder ({exc.strerror or exc})"
        ) from None
    if is_a_file:
        raise OutputFolderError(f"{option} {path} exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True, mode=mode)
    except FileExistsError:  # a parent, or the path itself since the check, is a file
        raise OutputFolderError(
            f"{option} {path}: cannot create the folder (a part of the path is a file)"
        ) from None
    except OSError as exc:
        raise OutputFolderError(
            f"{option} {path}: cannot create the folder ({exc.strerror or exc})"
        ) from None
    # access(2) also refuses writes on a read-only file system, even to root.
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputFolderError(f"{option} {path}: this user cannot write in the folder")
    # Yet it lets root through where no file can be made (sysfs, procfs: `--out /sys/kernel/mm`
    # failed later, on the run's lock file): one is made and removed to be sure.
    try:
        descriptor, probe = tempfile.mkstemp(prefix=WRITE_PROBE_PREFIX, dir=path)
    except OSError as exc:
        raise OutputFolderError(
            f"{option} {path}: cannot write in the folder ({exc.strerror or exc})"
        ) from None
    os.close(descriptor)
    with contextlib.suppress(OSError):
        os.unlink(probe)
    return path

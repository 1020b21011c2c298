"""The folders the `swarm` commands write into: checked before any work starts.

`swarm sim --out`, `swarm up --out`, `swarm tune --out`, `swarm dashboard --out` and the DIR of
`swarm credentials` all name a folder that may not exist yet.  A path that cannot be one (a
file, a path under a file, a read-only or pseudo file system, a folder without write
permission, a sysfs folder that access(2) calls writable for root) used to surface as a
traceback from deep inside the run, in `swarm sim`'s case only after the whole simulation had
run.  `prepare_output_folder` creates the folder up front and says in one line, naming the
option, why it cannot: a symbolic link to nothing on the way is named as one, and a path too
long for the files the command writes in it is refused before any folder is made.  A refused
folder leaves nothing behind (the folders made for it are removed again).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

from services.path_arguments import broken_link_problem

DEFAULT_FOLDER_MODE = 0o777
"""The mode `mkdir` is given (less the umask), as `Path.mkdir` gives by default."""


WRITE_PROBE_PREFIX = ".swarm-write-check-"
"""The name of the empty file made and removed in a folder to see that files can be made there."""
TEMPORARY_RANDOM_CHARS = 8
"""The random characters `tempfile.mkstemp` adds to a temporary file's prefix."""
DEFAULT_PATH_MAX = 4096
"""PATH_MAX where the file system does not say (Linux's)."""


class OutputFolderError(ValueError):
    """An output folder that cannot be created or written; the message names the option."""


def prepare_output_folder(
    path: Path,
    option: str,
    *,
    mode: int = DEFAULT_FOLDER_MODE,
    writes: Sequence[str] = (),
) -> Path:
    """Create `path` and its parents (new folders get `mode`), and check this process can
    write in it; returns `path`.

    `writes` names the files the command will write in the folder (relative paths): the path
    of each, as its atomic write's temporary file (swarm_config/atomic_files.py), must be one
    the file system takes.  A refused folder is left as it was: the folders made here for it
    are removed again.

    Raises OutputFolderError, whose message starts with `option` and the path, when `path` is
    not a folder, cannot be created, is too long for the files written in it, or is not
    writable (access(2) says so, or a file cannot be made in it).
    """
    try:
        is_a_file = path.exists() and not path.is_dir()
    except OSError as exc:  # a name too long for the file system, a loop of links
        raise OutputFolderError(
            f"{option} {path}: cannot use the folder ({exc.strerror or exc})"
        ) from None
    if is_a_file:
        raise OutputFolderError(f"{option} {path} exists and is not a folder")
    too_long = _too_long_problem(path, writes)
    if too_long is not None:
        raise OutputFolderError(f"{option} {path}: {too_long}")
    made = _missing_folders(path)
    try:
        _make_writable_folder(path, option, mode)
    except OutputFolderError:
        for folder in made:  # the deepest first; one another process filled stays
            with contextlib.suppress(OSError):
                os.rmdir(folder)
        raise
    return path


def _make_writable_folder(path: Path, option: str, mode: int) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True, mode=mode)
    except OSError as exc:
        # A part of the path that is a symbolic link to nothing (mkdir says "File exists",
        # and a loop "Too many levels of symbolic links") is named as what it is.
        broken = _broken_link_on_the_way(path)
        if broken is not None:
            reason = broken
        elif isinstance(exc, FileExistsError):  # a parent, or the path since the check, is a file
            reason = "a part of the path is a file"
        else:
            reason = exc.strerror or str(exc)
        raise OutputFolderError(f"{option} {path}: cannot create the folder ({reason})") from None
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


def _missing_folders(path: Path) -> list[Path]:
    """`path` and those of its parents that do not exist yet, the deepest first."""
    missing: list[Path] = []
    for folder in (path, *path.parents):
        if os.path.lexists(folder):
            break
        missing.append(folder)
    return missing


def _broken_link_on_the_way(path: Path) -> str | None:
    """What the first part of `path` that is a symbolic link to nothing is, else None."""
    for part in (*reversed(path.parents), path):
        if not os.path.isdir(part):
            return broken_link_problem(part)
    return None


def _too_long_problem(path: Path, writes: Sequence[str]) -> str | None:
    """Why the file system would refuse the path of a file written in `path` (the write check's
    own file, then each of `writes` as its atomic write's temporary file), else None: a path
    too long for it surfaced as "File name too long" after `swarm sim` had run, its folders
    made."""
    limit = _path_max(path)
    names = [WRITE_PROBE_PREFIX + TEMPORARY_RANDOM_CHARS * "x"]
    for written in writes:
        folder, _, name = written.rpartition("/")
        names.append(f"{folder}/" * bool(folder) + f".{name}." + TEMPORARY_RANDOM_CHARS * "x")
    longest = max(len(os.fsencode(os.path.join(path, name))) for name in names)
    if longest < limit:
        return None
    length = len(os.fsencode(path))
    return (
        f"the path ({length:,} bytes) leaves no room for the names of the files written in "
        f"it ({longest - length:,} bytes more; the file system takes paths of at most "
        f"{limit - 1:,} bytes)"
    )


def _path_max(path: Path) -> int:
    """The length a path may not reach (bytes, its terminating NUL included) on the file
    system `path` would be on: that of its deepest existing folder."""
    for folder in (path, *path.parents):
        if os.path.isdir(folder):
            with contextlib.suppress(OSError, ValueError):
                return os.pathconf(folder, "PC_PATH_MAX")
            break
    return DEFAULT_PATH_MAX

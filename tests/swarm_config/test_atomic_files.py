"""A file written whole or not at all, and a failed write that names the file and keeps the old."""

import os
import resource
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from swarm_config.atomic_files import (
    PRIVATE_FILE_MODE,
    FileWriteError,
    write_file_atomically,
)

ROOT = Path(__file__).resolve().parents[2]


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_file_gets_its_bytes_and_mode_and_its_folder_is_made(tmp_path: Path) -> None:
    target = tmp_path / "new" / "folder" / "summary.json"
    write_file_atomically(target, b"{}\n")
    assert target.read_bytes() == b"{}\n"
    assert _mode(target) == 0o644
    write_file_atomically(target, b"secret", mode=PRIVATE_FILE_MODE, durable=False)
    assert target.read_bytes() == b"secret"
    assert _mode(target) == 0o600
    assert sorted(p.name for p in target.parent.iterdir()) == ["summary.json"]


def test_a_target_that_is_a_folder_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    target = tmp_path / "summary.json"
    target.mkdir()
    (target / "inside").write_text("kept")
    with pytest.raises(FileWriteError) as caught:
        write_file_atomically(target, b"{}")
    assert str(caught.value).startswith(f"cannot write {target}: ")
    assert (target / "inside").read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]  # no temporary left


def test_a_folder_that_cannot_be_made_is_a_file_write_error(tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(FileWriteError) as caught:
        write_file_atomically(tmp_path / "a_file" / "summary.json", b"{}")
    assert isinstance(caught.value, OSError)  # callers that catch OSError still do
    assert caught.value.filename == str(tmp_path / "a_file" / "summary.json")


def test_a_write_the_file_system_refuses_part_way_keeps_the_old_file(tmp_path: Path) -> None:
    """A real short write: the child may write files of at most 100 bytes (RLIMIT_FSIZE), as a
    disk that fills up would refuse the rest; Python ignores SIGXFSZ, so the write fails."""
    target = tmp_path / "checkpoint.bin"
    target.write_bytes(b"old")
    script = (
        "import sys; from pathlib import Path\n"
        "from swarm_config.atomic_files import FileWriteError, write_file_atomically\n"
        "try:\n"
        f"    write_file_atomically(Path({str(target)!r}), b'x' * 100_000)\n"
        "except FileWriteError as exc:\n"
        "    print(exc); sys.exit(3)\n"
    )

    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))

    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        preexec_fn=limit_file_size,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 3, done.stderr
    assert done.stdout.startswith(f"cannot write {target}: File too large")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.bin"]

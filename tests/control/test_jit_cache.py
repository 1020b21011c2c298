"""Where numba caches compiled kernels (robot_firmware/control/kernels.py `use_jit_cache`): a
directory per state of the sources, so that a cached kernel never runs a callee of another
file as that callee was before an edit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from robot_firmware.control import kernels

ROOT = Path(__file__).resolve().parents[2]
ENVIRONMENT = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}

CALLEE = """
from numba import njit

@njit(cache=True)
def gain():
    return {value}
"""

CALLER = """
from numba import njit

from callee import gain

@njit(cache=True)
def doubled_gain():
    return 2 * gain()
"""

RUN = """
import sys
from pathlib import Path
from robot_firmware.control import kernels
sources, root = Path(sys.argv[1]), Path(sys.argv[2])
print(kernels.use_jit_cache([sources / "a", sources / "b"], root))
sys.path[:0] = [str(sources / "a"), str(sources / "b")]
import caller
print(caller.doubled_gain())
"""


def _run(sources: Path, root: Path) -> tuple[Path, int]:
    """The cache directory chosen and what the cached caller returns, in a new process."""
    ran = subprocess.run(
        [sys.executable, "-c", RUN, str(sources), str(root)],
        cwd=ROOT,
        env={**ENVIRONMENT, "SWARM_KERNELS": "jit"},
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    directory, value = ran.stdout.split()
    return Path(directory), int(value)


@pytest.mark.skipif(kernels.MODE != "jit", reason="numba's JIT is not in use")
def test_a_callee_edited_in_another_file_is_compiled_again(tmp_path: Path) -> None:
    sources, root = tmp_path / "src", tmp_path / "cache"
    (sources / "a").mkdir(parents=True)
    (sources / "b").mkdir()
    callee = sources / "a" / "callee.py"
    callee.write_text(CALLEE.format(value=1))
    (sources / "b" / "caller.py").write_text(CALLER)

    first_dir, first = _run(sources, root)
    again_dir, again = _run(sources, root)
    assert (first, again) == (2, 2)
    assert again_dir == first_dir and first_dir.parent == root
    assert list(first_dir.rglob("caller.doubled_gain-*.nbi")), "the caller was not cached"

    callee.write_text(CALLEE.format(value=5))
    edited_dir, edited = _run(sources, root)
    assert edited == 10
    assert edited_dir != first_dir
    assert not first_dir.exists(), "the directory of the old sources is left behind"


def test_the_directory_is_named_after_every_compiled_source(tmp_path: Path) -> None:
    """The world's and the batch simulator's kernels call these: their files count too."""
    sources = [tmp_path / "control", tmp_path / "world"]
    for directory in sources:
        directory.mkdir()
        (directory / "kernel.py").write_text("x = 1\n")
    before = kernels.source_hash(sources)
    (sources[1] / "kernel.py").write_text("x = 2\n")
    assert kernels.source_hash(sources) != before
    assert {d.name for d in kernels.COMPILED_SOURCE_DIRS} >= {"control", "world", "sim"}

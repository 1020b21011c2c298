"""A command's stdout on a device that refuses writes (services/standard_output.py)."""

from __future__ import annotations

import errno
import io
import os
from pathlib import Path

import pytest

from services.standard_output import GuardedOutput
from tests.support.full_device import DEV_FULL, run_with_stdout_on_a_full_device

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
needs_dev_full = pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full on this system")


class RefusingStream(io.StringIO):
    """A text stream whose device answers every write with `error`."""

    def __init__(self, error: int) -> None:
        super().__init__()
        self.error = error

    def write(self, text: str) -> int:
        raise OSError(self.error, os.strerror(self.error))

    def fileno(self) -> int:
        raise io.UnsupportedOperation("no descriptor")


def test_a_refused_write_is_said_once_and_the_rest_is_dropped(
    capsys: pytest.CaptureFixture[str],
) -> None:
    guarded = GuardedOutput(RefusingStream(errno.ENOSPC), "status")
    assert guarded.write("first\n") == len("first\n")
    print("second", file=guarded, flush=True)
    guarded.flush()
    assert isinstance(guarded.lost, OSError) and guarded.lost.errno == errno.ENOSPC
    said = capsys.readouterr().err.splitlines()
    assert said == [
        "swarm status: cannot write to standard output (No space left on device); the rest "
        "of this command's output is dropped"
    ]


def test_other_errors_and_good_writes_pass_through() -> None:
    kept = io.StringIO()
    guarded = GuardedOutput(kept, "status")
    print("hello", file=guarded)
    assert kept.getvalue() == "hello\n" and guarded.lost is None
    assert guarded.getvalue() == "hello\n"  # the inner stream's own attributes
    with pytest.raises(OSError, match="Bad file descriptor"):
        GuardedOutput(RefusingStream(errno.EBADF), "status").write("x")


@needs_dev_full
def test_swarm_sim_with_stdout_on_a_full_device_writes_its_summary_and_says_so(
    tmp_path: Path,
) -> None:
    # Before: a traceback from the first print, status 1.
    out = tmp_path / "out"
    ran = run_with_stdout_on_a_full_device(
        ["sim", "--scenario", str(PAPER), "--out", str(out)]
        + ["--duration", "1", "--no-figures", "--no-compare"],
        ROOT,
    )
    assert ran.returncode == 1, ran.stderr
    assert "Traceback" not in ran.stderr and "Exception ignored" not in ran.stderr, ran.stderr
    assert ran.stderr.count("cannot write to standard output (No space left on device)") == 1
    assert (out / "summary.json").is_file()

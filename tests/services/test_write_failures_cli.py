"""A file a command cannot write (a full disk, a folder in its place) is one line and status 1.

Each test puts a folder where the command writes a file: a write the file system refuses, as a
full disk would, without needing one.  Before, each of these was a traceback (`swarm sim` only
after the whole simulation had run).
"""

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def _swarm(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(ROOT / "swarm"), *argv], capture_output=True, text=True, cwd=ROOT, timeout=300
    )


def _one_line_status_1(done: subprocess.CompletedProcess[str]) -> str:
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    return done.stderr.strip().splitlines()[-1]


def test_sim_names_the_figure_it_cannot_write_and_keeps_the_summary(tmp_path: Path) -> None:
    (tmp_path / "fig11_paths.png").mkdir()
    done = _swarm("sim", "--scenario", str(PAPER), "--out", str(tmp_path), "--duration", "1")
    line = _one_line_status_1(done)
    assert line == f"swarm sim: cannot write {tmp_path / 'fig11_paths.png'}: Is a directory"
    assert (tmp_path / "summary.json").is_file()


def test_credentials_names_the_file_it_cannot_write(tmp_path: Path) -> None:
    (tmp_path / "world.json").mkdir(parents=True)
    line = _one_line_status_1(_swarm("credentials", str(tmp_path)))
    assert line == f"swarm credentials: cannot write {tmp_path / 'world.json'}: Is a directory"


def test_up_that_cannot_write_its_lock_starts_nothing(tmp_path: Path) -> None:
    (tmp_path / ".swarm-up.lock").mkdir()
    done = _swarm("up", "--out", str(tmp_path), "--no-dashboard", "--port", "9")
    line = _one_line_status_1(done)
    assert line == f"swarm up: cannot write {tmp_path / '.swarm-up.lock'}: Is a directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".swarm-up.lock"]


def test_tune_that_cannot_checkpoint_says_how_to_go_on(tmp_path: Path) -> None:
    (tmp_path / "ofa" / "convergence.csv").mkdir(parents=True)
    done = _swarm(
        "tune",
        "--scenario",
        str(PAPER),
        "--out",
        str(tmp_path),
        "--budget",
        "30",
        "--duration",
        "1",
    )
    line = _one_line_status_1(done)
    assert line.startswith(
        f"swarm tune: cannot write {tmp_path / 'ofa' / 'convergence.csv'}: Is a directory; ofa is "
        f"checkpointed in {tmp_path / 'ofa'}"
    )
    assert line.endswith("make room, then run the same command with --resume")

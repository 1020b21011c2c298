"""`swarm scenario generate`: writes an ordinary scenario file; mistakes are one line, exit 2."""

import os
import socket
import stat
from pathlib import Path

import pytest

from services.cli.main import main
from swarm_config.scenario import load_scenario


def test_generate_writes_a_scenario_the_swarm_can_load(tmp_path: Path) -> None:
    out = tmp_path / "wedge.yaml"
    code = main(
        ["scenario", "generate", "--robots", "12", "--formation", "wedge", "--out", str(out)]
    )
    assert code == 0
    scenario = load_scenario(out)
    assert scenario.robot_names == tuple(f"robot{i}" for i in range(1, 13))
    assert scenario.name == "wedge-12"


def test_the_leader_alone_runs_and_its_summary_lines_say_n_a_for_the_formation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "one.yaml"
    assert main(["scenario", "generate", "--robots", "1", "--out", str(out)]) == 0
    assert f"wrote {out} (1 robot, wedge)" in capsys.readouterr().out
    argv = ["sim", "--scenario", str(out), "--out", str(tmp_path / "run"), "--duration", "1"]
    assert main([*argv, "--no-figures"]) == 0
    compared = [line for line in capsys.readouterr().out.splitlines() if "fitness (16)" in line]
    assert len(compared) == 2 and all(", formation n/a, " in line for line in compared), compared


def test_equal_arguments_write_identical_files(tmp_path: Path) -> None:
    args = ["scenario", "generate", "--robots", "9", "--formation", "grid", "--trajectory",
            "lemniscate", "--obstacles", "2", "--seed", "4"]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "a.yaml")]) == 0
    assert main([*args, "--out", str(tmp_path / "b.yaml")]) == 0
    assert (tmp_path / "a.yaml").read_bytes() == (tmp_path / "b.yaml").read_bytes()


def test_the_file_names_the_command_that_recreates_it(tmp_path: Path) -> None:
    first = tmp_path / "first.yaml"
    assert main(["scenario", "generate", "--robots", "5", "--out", str(first)]) == 0
    command = first.read_text().splitlines()[1].lstrip("# ").split()
    assert command[:3] == ["swarm", "scenario", "generate"]
    again = tmp_path / "again.yaml"
    assert main([*command[1:], "--out", str(again)]) == 0
    assert again.read_bytes() == first.read_bytes()


@pytest.mark.parametrize(
    "args",
    [
        ["--robots", "4", "--speed-mps", "0.123456", "--spacing-m", "1.23456"],
        ["--robots", "3", "--speed-mps", "0.00001"],
        [
            "--robots",
            "3",
            "--speed-mps",
            "1e-5",
            "--size-m",
            "3.3333333333333335",
            "--obstacles",
            "0",
        ],
        [
            "--robots",
            "7",
            "--formation",
            "grid",
            "--trajectory",
            "lemniscate",
            "--duration",
            "12.345678901",
        ],
        ["--robots", "5", "--trajectory", "polyline", "--speed-mps", "0.30000000000000004"],
        [
            "--robots",
            "2",
            "--formation",
            "line",
            "--obstacles",
            "0",
            "--seed",
            str(2**70),
            "--name=-dash",
        ],
    ],
)
def test_the_header_command_recreates_the_file_for_unusual_values(
    tmp_path: Path, args: list[str]
) -> None:
    # Before, the header rounded the flags (--spacing-m 1.23456 as 1.2346: other slots;
    # --speed-mps 0.00001 as 0.0: refused).
    first = tmp_path / "first.yaml"
    assert main(["scenario", "generate", *args, "--out", str(first)]) == 0
    header = first.read_text().splitlines()[1]
    assert header.startswith("#   swarm scenario generate ")
    again = tmp_path / "again.yaml"
    assert main([*header.split()[2:], "--out", str(again)]) == 0
    assert again.read_bytes() == first.read_bytes()


@pytest.mark.parametrize(
    "args",
    [
        ["--robots", "0"],
        ["--robots", "three"],
        ["--robots", "3", "--formation", "star"],
        ["--robots", "3", "--spacing-m", "0.5"],
        ["--robots", "3", "--obstacles", "40"],
        ["--formation", "line"],
    ],
)
def test_a_bad_argument_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    out = tmp_path / "never.yaml"
    try:
        code = main(["scenario", "generate", *args, "--out", str(out)])
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code  # type: ignore[assignment]
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_an_unwritable_destination_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "missing" / "x.yaml"
    assert main(["scenario", "generate", "--robots", "3", "--out", str(out)]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert main(["scenario", "generate", "--robots", "3", "--out", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_a_file_that_holds_another_scenario_is_replaced_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, a hand-edited scenario given as --out was overwritten without a word.
    mine = tmp_path / "mine.yaml"
    mine.write_text("# my own scenario, edited by hand\n")
    args = ["scenario", "generate", "--robots", "4", "--out", str(mine)]
    assert main(args) == 2
    assert "exists and holds another scenario; give --force" in capsys.readouterr().err
    assert mine.read_text() == "# my own scenario, edited by hand\n"
    assert main([*args, "--force"]) == 0
    generated = mine.read_bytes()
    assert main(args) == 0  # the same command again: the file already holds what it writes
    assert mine.read_bytes() == generated


def _make_destination(kind: str, path: Path) -> None:
    if kind == "device node":
        try:
            os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # a /dev/null of its own
        except PermissionError:
            pytest.skip("making a device node needs root")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        with socket.socket(socket.AF_UNIX) as listener:
            listener.bind(str(path))
    elif kind == "dangling symlink":
        path.symlink_to(path.parent / "nowhere" / "x.yaml")
    else:
        (path.parent / "target.yaml").write_text("# the link's target\n")
        path.symlink_to(path.parent / "target.yaml")


@pytest.mark.parametrize(
    "kind", ["device node", "fifo", "socket", "dangling symlink", "symlink to a file"]
)
def test_an_out_that_is_not_a_regular_file_is_refused_and_left_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str
) -> None:
    # Before, the file was renamed over it: as root, `--out /dev/null` replaced the system's
    # /dev/null with a regular file, and a FIFO or a symlink became a regular file, exit 0.
    out = tmp_path / "out"
    _make_destination(kind, out)
    before = out.lstat()
    for force in ([], ["--force"]):
        assert main(["scenario", "generate", "--robots", "3", "--out", str(out), *force]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1, err
        assert f"--out {out} " in err
        after = out.lstat()
        assert (after.st_mode, after.st_ino, after.st_size) == (
            before.st_mode,
            before.st_ino,
            before.st_size,
        )
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "target.yaml") == ["out"]

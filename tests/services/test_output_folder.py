"""Output folders (services/output_folder.py): made up front, or one line naming the option."""

import errno
import os
import stat
from pathlib import Path

import pytest

from services.cli.main import main
from services.output_folder import OutputFolderError, prepare_output_folder
from swarm_config.credentials import generate_credential_set, write_credential_set

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def test_a_missing_folder_and_its_parents_are_made(tmp_path: Path) -> None:
    folder = tmp_path / "a" / "b" / "run"
    assert prepare_output_folder(folder, "--out") == folder
    assert folder.is_dir()
    assert prepare_output_folder(folder, "--out") == folder  # an existing folder is fine


def test_a_new_folder_gets_the_mode_asked_for(tmp_path: Path) -> None:
    folder = tmp_path / "private"
    prepare_output_folder(folder, "DIR", mode=0o700)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_a_file_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    file = tmp_path / "summary.json"
    file.write_bytes(b"kept")
    with pytest.raises(OutputFolderError, match=r"^--out .*json exists and is not a folder"):
        prepare_output_folder(file, "--out")
    with pytest.raises(OutputFolderError, match=r"^--out .*summary\.json/run: cannot create"):
        prepare_output_folder(file / "run", "--out")
    assert file.read_bytes() == b"kept"


def test_a_folder_this_user_cannot_write_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # access(2) is what answers for a read-only file system or a folder of another user; this
    # process may be root, which permissions do not stop, so the answer is given here.
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(OutputFolderError, match="cannot write in the folder"):
        prepare_output_folder(tmp_path, "--out")


def _dashboard_credentials(tmp_path: Path) -> Path:
    written = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ["robot1", "robot2", "robot3"])
    )
    return written["dashboard"]


@pytest.mark.parametrize("command", ["sim", "up", "tune", "dashboard", "credentials"])
@pytest.mark.parametrize("under_a_file", [False, True], ids=["a file", "under a file"])
def test_every_command_that_writes_a_folder_refuses_a_bad_one_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, under_a_file: bool
) -> None:
    file = tmp_path / "taken"
    file.write_bytes(b"kept")
    target = str(file / "run" if under_a_file else file)
    scenario = ["--scenario", str(PAPER)]
    argv = {
        "sim": ["sim", *scenario, "--duration", "1", "--out", target],
        "up": ["up", *scenario, "--no-dashboard", "--duration", "1", "--out", target],
        "tune": ["tune", *scenario, "--budget", "25", "--out", target],
        "dashboard": [
            "dashboard",
            *scenario,
            "--credentials",
            str(_dashboard_credentials(tmp_path)),
            "--out",
            target,
        ],
        "credentials": ["credentials", *scenario, target],
    }[command]
    option = "DIR" if command == "credentials" else "--out"
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"swarm {command}: {option} {target}"), lines[0]
    expected = "cannot create the folder" if under_a_file else "exists and is not a folder"
    assert expected in lines[0]
    assert file.read_bytes() == b"kept"


def test_a_folder_where_no_file_can_be_made_is_refused_and_left_empty(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A pseudo file system (sysfs) lets root pass access(2) and refuses every new file; before,
    # the folder was taken and `swarm up` failed later on its lock file, status 1.
    real_open = os.open

    def refuse_new_files(path: str, flags: int, *rest: int, **kwargs: object) -> int:
        if flags & os.O_CREAT and Path(path).parent == tmp_path:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), path)
        return real_open(path, flags, *rest, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "open", refuse_new_files)
    with pytest.raises(
        OutputFolderError, match=r"^--out .*: cannot write in the folder \(Permission denied\)$"
    ):
        prepare_output_folder(tmp_path, "--out")
    monkeypatch.undo()
    assert prepare_output_folder(tmp_path, "--out") == tmp_path
    assert list(tmp_path.iterdir()) == []  # the file made to check is gone


SYSFS_FOLDER = Path("/sys/kernel/mm")


@pytest.mark.skipif(
    not (SYSFS_FOLDER.is_dir() and os.access(SYSFS_FOLDER, os.W_OK | os.X_OK)),
    reason="needs a sysfs folder access(2) calls writable (as root)",
)
@pytest.mark.parametrize("command", ["up", "credentials"])
def test_a_sysfs_folder_is_refused_naming_the_option_with_status_2(
    capsys: pytest.CaptureFixture[str], command: str
) -> None:
    # Before: "swarm up: cannot write /sys/kernel/mm/.swarm-up.lock: Permission denied",
    # status 1, where every other folder that cannot be written is named by its option, status 2.
    argv = {
        "up": ["up", "--no-dashboard", "--port", "9", "--out", str(SYSFS_FOLDER)],
        "credentials": ["credentials", str(SYSFS_FOLDER)],
    }[command]
    option = "--out" if command == "up" else "DIR"
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [
        f"swarm {command}: {option} {SYSFS_FOLDER}: cannot write in the folder (Permission denied)"
    ], lines


@pytest.mark.parametrize("below", [False, True], ids=["the folder", "a parent"])
def test_a_symbolic_link_to_nothing_is_named_as_one(tmp_path: Path, below: bool) -> None:
    # Before: "cannot create the folder (a part of the path is a file)".
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere" / "x")
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    for link, what in (
        (dangling, f"{dangling} is a symbolic link to {tmp_path / 'nowhere' / 'x'}, which "),
        (loop, f"{loop} is a symbolic link in a loop of links"),
    ):
        target = link / "run" if below else link
        with pytest.raises(OutputFolderError) as info:
            prepare_output_folder(target, "--out")
        assert str(info.value).startswith(f"--out {target}: cannot create the folder ({what}")
        assert link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling", "loop"]


def _path_of_length(root: Path, length: int) -> Path:
    """A path under `root` of `length` bytes, in names of 20 characters at most."""
    path = str(root)
    while len(path) < length:
        path += "/" + "d" * min(20, length - len(path) - 1)
    assert len(path) == length
    return Path(path)


def test_a_path_too_long_for_the_files_written_in_it_is_refused_before_any_folder(
    tmp_path: Path,
) -> None:
    # Before, the folders were made (under PATH_MAX), the write check failed in the deepest,
    # and every folder made stayed.
    folder = _path_of_length(tmp_path, os.pathconf(tmp_path, "PC_PATH_MAX") - 10)
    with pytest.raises(OutputFolderError) as info:
        prepare_output_folder(folder, "--out")
    assert str(info.value).startswith(f"--out {folder}: the path ({len(str(folder)):,} bytes)")
    assert "leaves no room for the names of the files written in it" in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_a_path_too_long_for_sims_figures_is_refused_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Room for the write check's file and summary.json, none for the figures' temporary files
    # (.fig12_leader_tracking_error.png.XXXXXXXX): before, the run went through and failed on
    # its second figure, status 1.
    folder = _path_of_length(tmp_path, os.pathconf(tmp_path, "PC_PATH_MAX") - 40)
    argv = ["sim", "--scenario", str(PAPER), "--duration", "0.5", "--out", str(folder)]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "leaves no room for the names of the files" in lines[0], lines
    assert list(tmp_path.iterdir()) == []
    assert main([*argv, "--no-figures"]) == 0  # summary.json alone fits
    assert [p.name for p in folder.iterdir()] == ["summary.json"]


def test_the_folders_made_for_a_refused_folder_are_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "a" / "b" / "run"
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(OutputFolderError, match="cannot write in the folder"):
        prepare_output_folder(folder, "--out")
    assert list(tmp_path.iterdir()) == []

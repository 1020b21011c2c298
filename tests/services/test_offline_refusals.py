"""Refusals of the offline commands and of the command line's own checks: each one line,
status 2, before anything starts, connects or is written."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from services.cli.main import main
from swarm_config.credentials import generate_credential_set, write_credential_set
from tests.support.cli_refusals import forbid_zenoh_sessions, refusal_lines

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
NOBODY = "tcp/127.0.0.1:9"


@pytest.fixture(autouse=True)
def _no_session_may_open(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each refusal here must come before the command opens a Zenoh session."""
    forbid_zenoh_sessions(monkeypatch)


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    lines = refusal_lines(argv, capsys)
    assert len(lines) == 1, lines
    return lines[0]


def _recording(tmp_path: Path) -> Path:
    """A file that starts as a Rerun recording does (never served here)."""
    from services.dashboard.recording_file import looks_like_recording

    path = tmp_path / "run.rrd"
    path.write_bytes(b"RRF2" + bytes(60))
    assert looks_like_recording(path)  # else the refusals below would be of another kind
    return path


def test_replay_refuses_one_port_for_both_servers_before_it_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, it printed the URL to open, then failed with Rerun's own message, status 1.
    recording = _recording(tmp_path)
    argv = ["replay", str(recording), "--web-port", "19191", "--grpc-port", "19191"]
    assert _refused(argv, capsys) == (
        "swarm replay: --web-port and --grpc-port are both 19191: the web viewer and the data "
        "server each need a port of their own"
    )


def test_replay_says_what_a_path_that_is_no_recording_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, each was "no such recording", though the path was there.
    dangling = tmp_path / "dangling.rrd"
    dangling.symlink_to(tmp_path / "gone.rrd")
    loop = tmp_path / "loop.rrd"
    loop.symlink_to(loop)
    for path, said in (
        (tmp_path, f"{tmp_path} is a folder, not a recording (give its .rrd file)"),
        (Path(os.devnull), f"{os.devnull} is not a regular file (a device, FIFO or socket)"),
        (dangling, f"{dangling} is a symbolic link to {tmp_path / 'gone.rrd'}, which does not"),
        (loop, f"{loop} is a symbolic link in a loop of links"),
        (tmp_path / "none.rrd", f"{tmp_path / 'none.rrd'}: no such recording"),
    ):
        assert _refused(["replay", str(path)], capsys).startswith(f"swarm replay: {said}")


@pytest.mark.parametrize(
    "argv",
    [
        ["status"],
        ["regs", "robot1"],
        ["fault", "kill", "robot1"],
    ],
)
def test_an_empty_swarm_name_is_refused_at_once(
    capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    # Before, '' was taken for lab: `swarm status` waited 5 s for a router.
    line = _refused([*argv, "--swarm", "", "--connect", NOBODY], capsys)
    assert line.startswith(f"swarm {argv[0]}: --swarm: swarm name '' must be 1-32 characters")


def test_credentials_refuse_an_empty_swarm_name_and_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, they were written for swarm lab.
    folder = tmp_path / "credentials"
    line = _refused(["credentials", str(folder), "--swarm", ""], capsys)
    assert line.startswith("swarm credentials: --swarm: swarm name '' must be 1-32 characters")
    assert not folder.exists()


def test_every_command_refuses_a_robot_named_as_a_service_naming_the_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, `swarm sim` ran it; `swarm credentials` refused it naming neither robot nor field.
    scenario = tmp_path / "world.yaml"
    scenario.write_text(
        PAPER.read_text().replace("  - role: follower", "  - name: world\n    role: follower", 1)
    )
    files = write_credential_set(
        tmp_path / "given", generate_credential_set("lab", ("robot1", "robot2", "robot3"))
    )
    for argv in (
        ["sim", "--scenario", str(scenario), "--out", str(tmp_path / "sim")],
        ["credentials", str(tmp_path / "credentials"), "--scenario", str(scenario)],
        ["world", "--scenario", str(scenario), "--credentials", str(files["world"])],
    ):
        try:
            status = main(argv)
        except SystemExit as exc:
            status = int(exc.code or 0)
        err = capsys.readouterr().err
        assert status == 2, err
        assert "  robots.1.name: 'world' is reserved for a service of the run" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["given", "world.yaml"]


def test_the_kernels_variable_is_the_kernels_modules() -> None:
    from robot_firmware.control import kernels
    from services.cli import main as cli

    assert cli.KERNELS_ENV == kernels.KERNELS_ENV

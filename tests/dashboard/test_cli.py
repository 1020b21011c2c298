"""`dashboard` and `replay` as a user meets them: mistakes exit 2 in one line; stop means stop."""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from services.dashboard.cli import add_dashboard_parsers, run_dashboard, run_replay
from services.dashboard.live import DashboardConfig, viewer_url
from swarm_config.credentials import DASHBOARD, generate_credential_set, write_credential_set
from tests.dashboard.conftest import (
    FINISHED_RECORDING_CHUNKS,
    PAPER,
    ROOT,
    Child,
    free_port,
    message_ends,
    read_recording,
    start,
)
from tests.support.waiting import wait_for


@pytest.fixture
def dashboard_credentials(tmp_path: Path) -> str:
    """A dashboard credentials file of swarm lab, as `swarm up` writes it."""
    paths = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1", "robot2", "robot3"))
    )
    return str(paths[DASHBOARD])


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="swarm")
    add_dashboard_parsers(parser.add_subparsers(dest="command"))
    return parser


def test_both_subcommands_are_registered_with_their_handlers(dashboard_credentials: str) -> None:
    parser = _parser()
    dashboard = parser.parse_args(["dashboard", "--scenario", str(PAPER), "--out", "runs/x"])
    assert dashboard.handler is run_dashboard
    # Unset flags leave the values to the settings file, the environment or the defaults.
    assert (dashboard.web_port, dashboard.grpc_port, dashboard.host) == (None, None, None)
    config = DashboardConfig.from_sources({"credentials": dashboard_credentials}, environ={})
    assert (config.web_port, config.grpc_port, config.host) == (9090, 9876, "127.0.0.1")
    assert config.server_memory_limit == "256MiB"
    replay = parser.parse_args(["replay", "runs/x/dashboard.rrd", "--web-port", "9191"])
    assert replay.handler is run_replay and replay.web_port == 9191


def test_missing_scenario_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = _parser().parse_args(["dashboard", "--scenario", str(tmp_path / "nope.yaml")])
    assert args.handler(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarm dashboard: ") and "nope.yaml" in err and len(err.splitlines()) == 1


def test_port_in_use_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], dashboard_credentials: str
) -> None:
    with socket.socket() as taken:
        taken.bind(("0.0.0.0", 0))
        taken.listen()
        port = taken.getsockname()[1]
        args = _parser().parse_args(
            ["dashboard", "--scenario", str(PAPER), "--grpc-port", str(port)]
            + ["--web-port", str(free_port()), "--credentials", dashboard_credentials]
        )
        assert args.handler(args) == 2
    assert f"port {port} is in use" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["dashboard", "replay"])
def test_a_port_outside_1_to_65535_is_a_usage_error_naming_the_flag(
    command: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    recording = tmp_path / "run.rrd"
    recording.write_bytes(b"")
    given = [str(recording)] if command == "replay" else []
    for option in ("--web-port", "--grpc-port"):
        with pytest.raises(SystemExit) as refused:
            _parser().parse_args([command, *given, option, "70000"])
        assert refused.value.code == 2
        err = capsys.readouterr().err
        assert f"argument {option}: '70000' is not a TCP port (1-65535)" in err, err


@pytest.mark.parametrize(
    ("option", "value", "problem"),
    [("--swarm", "Bad Name", "swarm name")],
)
def test_bad_settings_are_usage_errors_naming_the_field(
    option: str,
    value: str,
    problem: str,
    capsys: pytest.CaptureFixture[str],
    dashboard_credentials: str,
) -> None:
    argv = ["dashboard", "--scenario", str(PAPER), "--credentials", dashboard_credentials]
    args = _parser().parse_args([*argv, option, value])
    assert args.handler(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarm dashboard: invalid dashboard settings") and problem in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("command", ["dashboard", "replay"])
@pytest.mark.parametrize(
    ("option", "value", "problem"),
    [
        ("--host", "*", "is not a host name or address"),
        ("--host", "http://lab:80", "without a scheme, port or path"),
        ("--host", "0.0.0.0", "the any-address"),
        ("--memory-limit", "-5", "is not a memory size"),
        ("--memory-limit", "150%", "at most 100%"),
    ],
)
def test_a_viewer_option_no_browser_or_server_can_use_is_a_usage_error_naming_the_flag(
    command: str,
    option: str,
    value: str,
    problem: str,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:
    given = [str(tmp_path / "run.rrd")] if command == "replay" else []
    with pytest.raises(SystemExit) as refused:
        _parser().parse_args([command, *given, option, value])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: {value!r}" in err and problem in err, err


def test_an_ipv6_host_is_bracketed_in_the_printed_url(dashboard_credentials: str) -> None:
    args = _parser().parse_args(["dashboard", "--host", "::1", "--memory-limit", "1.5GiB"])
    assert (args.host, args.memory_limit) == ("[::1]", "1.5GiB")
    assert viewer_url(args.host, 9090, 9876).startswith("http://[::1]:9090/?url=")


def test_a_settings_file_with_a_bad_host_names_the_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dashboard_credentials: str
) -> None:
    settings = tmp_path / "dashboard.yaml"
    settings.write_text("host: lab host\nserver_memory_limit: lots\n")
    argv = ["dashboard", "--scenario", str(PAPER), "--credentials", dashboard_credentials]
    args = _parser().parse_args([*argv, "--config", str(settings)])
    assert args.handler(args) == 2
    err = capsys.readouterr().err
    assert "invalid dashboard settings (2 problems)" in err, err
    assert "  host: 'lab host' is not a host name or address" in err, err
    assert "  server_memory_limit: 'lots' is not a memory size" in err, err
    assert "Traceback" not in err


def test_replay_of_a_missing_file_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = _parser().parse_args(["replay", str(tmp_path / "none.rrd")])
    assert args.handler(args) == 2
    assert "no such recording" in capsys.readouterr().err


def test_replay_of_a_file_that_is_no_recording_is_a_usage_error(tmp_path: Path) -> None:
    # Before, Rerun's server started on it: "No importer support" in Rerun's own log format,
    # or, for an empty file, a server serving nothing until stopped.
    for name, content in (("notes.rrd", b"robot1 ran well\n"), ("empty.rrd", b"")):
        path = tmp_path / name
        path.write_bytes(content)
        argv = [sys.executable, "-m", "services.dashboard", "replay", str(path)]
        argv += ["--web-port", str(free_port()), "--grpc-port", str(free_port())]
        refused = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert refused.returncode == 2, refused.stderr
        assert f"{path} is not a Rerun recording" in refused.stderr


def _start_without_router(out: Path, children: list[Child], credentials: str) -> Child:
    """`swarm dashboard --out OUT` with no router to reach, up to its printed URL."""
    argv = ["-m", "services.dashboard", "dashboard", "--scenario", str(PAPER)]
    argv += ["--credentials", credentials]
    argv += ["--connect", f"tcp/127.0.0.1:{free_port()}", "--out", str(out)]
    argv += ["--web-port", str(free_port()), "--grpc-port", str(free_port())]
    dashboard = start("dashboard", argv, out / "logs")
    children.append(dashboard)
    dashboard.wait_for_line("open http://127.0.0.1:")
    return dashboard


def test_dashboard_waiting_for_an_absent_router_stops_on_sigterm(
    tmp_path: Path, children: list[Child], dashboard_credentials: str
) -> None:
    dashboard = _start_without_router(tmp_path, children, dashboard_credentials)
    assert dashboard.stop(signal.SIGTERM, timeout_s=15) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean stop writes the footer: no legacy warning
        recording = read_recording(tmp_path / "dashboard.rrd")
    assert recording["/map/reference_path"].static


def test_a_restarted_dashboard_cuts_a_half_written_chunk_off_the_kept_file(
    tmp_path: Path, children: list[Child], dashboard_credentials: str, finished_recording: bytes
) -> None:
    # What a kill in the middle of a write leaves: no footer, and a message without its end.
    whole = message_ends(finished_recording)[-3]
    (tmp_path / "dashboard.rrd").write_bytes(finished_recording[: whole + 40])
    dashboard = _start_without_router(tmp_path, children, dashboard_credentials)
    assert dashboard.stop(signal.SIGTERM, timeout_s=15) == 0
    kept = tmp_path / "dashboard-1.rrd"
    assert f"previous recording kept as {kept}" in dashboard.output()
    assert "40 bytes cut off its end" in dashboard.output()
    assert kept.read_bytes() == finished_recording[:whole]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no footer: read as a legacy file
        assert read_recording(kept)["/map/robots/robot1"].rows == FINISHED_RECORDING_CHUNKS - 1


def test_a_second_dashboard_recording_into_the_same_folder_is_refused(
    tmp_path: Path, children: list[Child], dashboard_credentials: str
) -> None:
    # Before, the second one moved the first one's live recording aside as an old one (and
    # could cut its end while it was being written).
    first = _start_without_router(tmp_path, children, dashboard_credentials)
    assert (tmp_path / "dashboard.rrd").exists()
    argv = ["-m", "services.dashboard", "dashboard", "--scenario", str(PAPER)]
    argv += ["--credentials", dashboard_credentials, "--out", str(tmp_path)]
    argv += ["--connect", f"tcp/127.0.0.1:{free_port()}"]
    argv += ["--web-port", str(free_port()), "--grpc-port", str(free_port())]
    second = start("second", argv, tmp_path / "logs")
    children.append(second)
    try:
        assert second.process.wait(timeout=60) == 2, second.output()
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the second dashboard runs:\n{second.output()}") from None
    assert (
        f"swarm dashboard: {tmp_path} is the recording folder of another `swarm dashboard` that "
        f"is still running (pid {first.process.pid})"
    ) in second.output()
    assert sorted(p.name for p in tmp_path.glob("*.rrd")) == ["dashboard.rrd"]
    assert first.stop(signal.SIGTERM, timeout_s=15) == 0
    assert "previous recording kept" not in first.output()


def _state(pid: int) -> str | None:
    """A process's state letter from /proc (Z: ended, not yet reaped), None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return None
    return next(line.split()[1] for line in status.splitlines() if line.startswith("State:"))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and PR_SET_PDEATHSIG")
def test_a_killed_replay_takes_reruns_server_with_it(
    tmp_path: Path, children: list[Child], finished_recording: bytes
) -> None:
    # Before, `kill -9` of `swarm replay` left Rerun's server serving, holding both ports.
    recording = tmp_path / "run.rrd"
    recording.write_bytes(finished_recording)
    argv = ["-m", "services.dashboard", "replay", str(recording)]
    argv += ["--web-port", str(free_port()), "--grpc-port", str(free_port())]
    replay = start("replay", argv, tmp_path / "logs")
    children.append(replay)
    replay.wait_for_line("open http://127.0.0.1:")
    pid = replay.process.pid

    def servers_started() -> list[int]:
        children_file = Path(f"/proc/{pid}/task/{pid}/children")
        return [int(child) for child in children_file.read_text().split()]

    # The URL is printed before Rerun's server is started: on a loaded machine the test may
    # look before the server exists.
    wait_for(servers_started, timeout_s=30)
    servers = servers_started()
    assert len(servers) == 1, servers
    replay.process.kill()
    replay.process.wait()
    try:
        wait_for(lambda: _state(servers[0]) in (None, "Z"), timeout_s=30)
    finally:
        if _state(servers[0]) not in (None, "Z"):
            os.kill(servers[0], signal.SIGKILL)  # what the test found left behind


def _listening_addresses(port: int) -> set[str]:
    """The local addresses of the TCP sockets listening on `port` (IPv4, /proc/net/tcp)."""
    addresses = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address_hex, port_hex = local.split(":")
        if state == "0A" and int(port_hex, 16) == port:  # 0A: LISTEN
            addresses.add(socket.inet_ntoa(bytes.fromhex(address_hex)[::-1]))
    return addresses


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads /proc/net/tcp")
@pytest.mark.parametrize(
    ("command", "extra", "expected"),
    [
        ("dashboard", [], "127.0.0.1"),
        ("dashboard", ["--bind", "0.0.0.0"], "0.0.0.0"),
        ("dashboard", ["--host", "robots.lab"], "0.0.0.0"),
        ("replay", [], "127.0.0.1"),
    ],
)
def test_the_data_server_listens_on_loopback_unless_the_browser_is_elsewhere(
    tmp_path: Path,
    children: list[Child],
    dashboard_credentials: str,
    finished_recording: bytes,
    command: str,
    extra: list[str],
    expected: str,
) -> None:
    # Before, Rerun's gRPC server listened on every interface: anyone who reached the machine
    # streamed the swarm's truth and telemetry from the dashboard, credentials or not.
    grpc_port = free_port()
    argv = ["-m", "services.dashboard", command, "--grpc-port", str(grpc_port)]
    argv += ["--web-port", str(free_port()), *extra]
    if command == "dashboard":
        argv += ["--scenario", str(PAPER), "--credentials", dashboard_credentials]
        argv += ["--connect", f"tcp/127.0.0.1:{free_port()}"]
    else:
        recording = tmp_path / "run.rrd"
        recording.write_bytes(finished_recording)
        argv.append(str(recording))
    server = start(command, argv, tmp_path / "logs")
    children.append(server)
    server.wait_for_line("open http://")
    wait_for(lambda: _listening_addresses(grpc_port), timeout_s=30)
    assert _listening_addresses(grpc_port) == {expected}
    assert server.stop(signal.SIGTERM, timeout_s=15) in (0, -signal.SIGTERM)

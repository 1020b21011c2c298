"""How a process's Zenoh runtimes are chosen (robot_firmware/net/session.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from robot_firmware.net.session import (
    CLIENT_ZENOH_RUNTIME,
    ROUTER_ZENOH_RUNTIME,
    ZENOH_RUNTIME_ENV,
    zenoh_runtime_while_opening,
)
from swarm_config.credentials import OPERATOR, generate_credential_set, write_credential_set

ROOT = Path(__file__).resolve().parents[2]


def test_a_session_opened_without_a_runtime_setting_gets_it_and_leaves_none(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(ZENOH_RUNTIME_ENV, raising=False)
    with zenoh_runtime_while_opening(CLIENT_ZENOH_RUNTIME):
        assert os.environ[ZENOH_RUNTIME_ENV] == CLIENT_ZENOH_RUNTIME
    # The launcher may restart the router after opening its own session: the router must not
    # inherit the clients' setting.
    assert ZENOH_RUNTIME_ENV not in os.environ


@pytest.mark.parametrize(
    ("setting", "kept"),
    [(CLIENT_ZENOH_RUNTIME, "app"), (ROUTER_ZENOH_RUNTIME, "rx")],
    ids=["client", "router"],
)
def test_each_setting_hands_every_other_runtime_over_to_one(setting: str, kept: str) -> None:
    others = {"app", "acc", "tx", "rx", "net"} - {kept}
    for runtime in others:
        assert f"{runtime}: (handover: {kept})" in setting
    assert f"{kept}:" not in setting


def test_a_runtime_setting_of_the_users_own_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    mine = "(rx: (worker_threads: 4))"
    monkeypatch.setenv(ZENOH_RUNTIME_ENV, mine)
    with zenoh_runtime_while_opening(ROUTER_ZENOH_RUNTIME):
        assert os.environ[ZENOH_RUNTIME_ENV] == mine
    assert os.environ[ZENOH_RUNTIME_ENV] == mine


def test_a_failed_open_leaves_no_setting_behind(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ZENOH_RUNTIME_ENV, raising=False)
    with pytest.raises(RuntimeError), zenoh_runtime_while_opening(CLIENT_ZENOH_RUNTIME):
        raise RuntimeError("no router there")
    assert ZENOH_RUNTIME_ENV not in os.environ


@pytest.mark.parametrize("command", [("status",), ("router", "--listen", "tcp/127.0.0.1:9")])
def test_a_runtime_setting_zenoh_cannot_read_is_one_line_naming_it(
    command: tuple[str, ...], tmp_path: Path
) -> None:
    # Before, Zenoh's panic reached every process of the swarm as a Python traceback.
    files = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1",))
    )
    argv = [sys.executable, "-m", "services.cli.main", *command]
    if command[0] == "status":
        argv += ["--connect", "tcp/127.0.0.1:9", "--credentials", str(files[OPERATOR])]
    refused = subprocess.run(
        argv,
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        env={**os.environ, ZENOH_RUNTIME_ENV: "garbage", "RUST_BACKTRACE": "0"},
    )
    assert refused.returncode == 2, refused.stderr
    last = refused.stderr.strip().splitlines()[-1]
    assert last.startswith(
        f"swarm {command[0]}: ${ZENOH_RUNTIME_ENV}='garbage' is not a runtime setting Zenoh can "
        "read"
    ), refused.stderr
    assert "Traceback" not in refused.stderr


PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


@pytest.mark.parametrize("process", ["robot", "world"])
def test_a_zenoh_config_of_the_users_own_that_fails_is_one_line(
    process: str, tmp_path: Path
) -> None:
    # Before: a traceback from zenoh.Config.from_file for a file that is no Zenoh config, and
    # from zenoh.open for a config that does not wait for the router.
    files = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1",))
    )
    not_waiting = tmp_path / "not-waiting.json5"
    not_waiting.write_text('{mode: "client", connect: {timeout_ms: 0}}\n')
    unreadable = tmp_path / "unreadable.json5"
    unreadable.write_text("{bad\n")
    identity = "robot1" if process == "robot" else "world"
    argv = [sys.executable, "-m", "services.cli.main", process, "--scenario", str(PAPER)]
    argv += ["--connect", "tcp/127.0.0.1:9", "--credentials", str(files[identity])]
    argv += ["--name", "robot1"] if process == "robot" else ["--out", str(tmp_path / "run")]
    for config, status, expected in (
        (not_waiting, 1, f"swarm {process}: cannot open its Zenoh session: Unable to connect"),
        (unreadable, 2, f"swarm {process}: {unreadable}: not a config Zenoh can read ("),
    ):
        ran = subprocess.run(
            argv,
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=60,
            env={**os.environ, "ZENOH_CONFIG": str(config)},
        )
        assert ran.returncode == status, ran.stderr
        assert "Traceback" not in ran.stderr and ".rs:" not in ran.stderr, ran.stderr
        assert ran.stderr.startswith(expected), ran.stderr

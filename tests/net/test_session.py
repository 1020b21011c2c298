"""How a process's Zenoh runtimes are chosen (robot_firmware/net/session.py)."""

from __future__ import annotations

import os

import pytest

from robot_firmware.net.session import (
    CLIENT_ZENOH_RUNTIME,
    ROUTER_ZENOH_RUNTIME,
    ZENOH_RUNTIME_ENV,
    zenoh_runtime_while_opening,
)


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

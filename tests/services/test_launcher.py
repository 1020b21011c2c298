"""The launcher's supervision of the world and its kill/restart verbs, with stand-in children."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    KillReply,
    ProcessRequest,
    RestartReply,
)
from services.launcher.launcher import WORLD_MAX_QUICK_DEATHS, Launcher, LaunchPlan
from tests.support.stand_in_processes import StandInFactory, StandInProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


@pytest.fixture
def launcher(tmp_path: Path) -> Iterator[Launcher]:
    plan = LaunchPlan(
        scenario=PAPER, robots=("robot1", "robot2"), out_dir=tmp_path, dashboard=False
    )
    launcher = Launcher(plan, factory=StandInFactory())  # type: ignore[arg-type]
    for name in launcher.children:
        launcher.start(name)
    yield launcher
    launcher.shutdown(grace_s=0.0)


def _world(launcher: Launcher) -> StandInProcess:
    process = launcher.children["world"].process
    assert isinstance(process, StandInProcess)
    return process


def test_a_world_that_dies_is_started_again(launcher: Launcher) -> None:
    first = _world(launcher)
    assert launcher.supervise_world() is None
    first.returncode = -9  # SIGKILLed from outside the launcher
    assert launcher.supervise_world() is None
    assert _world(launcher) is not first and _world(launcher).returncode is None
    assert launcher.children["world"].restarts == 1


def test_a_clean_world_exit_ends_the_run(launcher: Launcher) -> None:
    _world(launcher).returncode = 0
    assert launcher.supervise_world() == 0
    assert launcher.children["world"].restarts == 0


def test_a_world_killed_through_the_admin_verb_stays_down_until_restarted(
    launcher: Launcher,
) -> None:
    handlers = launcher.admin_handlers()
    killed = handlers["kill"](ProcessRequest(process="world").model_dump_json().encode())
    assert killed == KillReply(killed=True)
    for _ in range(3):
        assert launcher.supervise_world() is None
    assert launcher.children["world"].restarts == 0 and not launcher.children["world"].running
    restarted = handlers["restart"](b'{"process": "world"}')
    assert isinstance(restarted, RestartReply) and restarted.restarted == "world"
    assert launcher.children["world"].running and launcher.supervise_world() is None


def test_a_world_that_cannot_start_ends_the_run(launcher: Launcher) -> None:
    for death in range(WORLD_MAX_QUICK_DEATHS):
        _world(launcher).returncode = 2
        outcome = launcher.supervise_world()
        assert outcome == (2 if death == WORLD_MAX_QUICK_DEATHS - 1 else None)


def test_an_unknown_process_is_refused_and_nothing_changes(launcher: Launcher) -> None:
    before = {name: child.process for name, child in launcher.children.items()}
    for body in (b'{"process": "robot9"}', b'{"robot": "robot1"}', b"kill"):
        reply = launcher.admin_handlers()["kill"](body)
        assert isinstance(reply, AdminError)
    reply = launcher.admin_handlers()["restart"](b'{"process": "robot9"}')
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNKNOWN_PROCESS
    assert "robot9" in reply.error and "world" in reply.error
    assert {name: child.process for name, child in launcher.children.items()} == before
    assert all(child.running for child in launcher.children.values())

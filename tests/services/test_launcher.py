"""The launcher's supervision of the world and its kill/restart/stop/cont verbs, with stand-in
children."""

from __future__ import annotations

import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    ContReply,
    KillReply,
    LauncherStatusReply,
    ProcessRequest,
    RestartReply,
    StopReply,
)
from services.launcher import launcher as launcher_module
from services.launcher.launcher import (
    WORLD_MAX_QUICK_DEATHS,
    Launcher,
    LaunchError,
    LaunchPlan,
)
from tests.integration.conftest import free_port
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


def _process(launcher: Launcher, name: str) -> StandInProcess:
    process = launcher.children[name].process
    assert isinstance(process, StandInProcess)
    return process


def _world(launcher: Launcher) -> StandInProcess:
    return _process(launcher, "world")


def _request(name: str) -> bytes:
    return ProcessRequest(process=name).model_dump_json().encode()


def _status(launcher: Launcher) -> LauncherStatusReply:
    reply = launcher.admin_handlers()["status"](b"")
    assert isinstance(reply, LauncherStatusReply)
    return reply


def test_a_world_that_dies_is_started_again(launcher: Launcher) -> None:
    first = _world(launcher)
    assert launcher.supervise_world() is None
    first.returncode = -9  # SIGKILLed from outside the launcher
    assert launcher.supervise_world() is None
    assert _world(launcher) is not first and _world(launcher).returncode is None
    assert launcher.children["world"].restarts == 1


def test_a_robot_that_ends_by_itself_is_reported_once_and_a_killed_one_not_at_all(
    launcher: Launcher, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level("WARNING", logger="swarm.launcher")
    _process(launcher, "robot1").returncode = 1  # crashed
    launcher.admin_handlers()["kill"](_request("robot2"))  # a power cut on purpose
    for _ in range(3):
        launcher.report_exits()
    reports = [r.getMessage() for r in caplog.records if "exited by itself" in r.getMessage()]
    assert reports == [
        "robot1 exited by itself (status 1); it stays down until `swarm restart robot1`: see "
        f"{launcher.children['robot1'].log_path}"
    ]
    launcher.start("robot1")  # restarted, then crashes again: reported again
    _process(launcher, "robot1").returncode = 1
    launcher.report_exits()
    assert sum("exited by itself" in r.getMessage() for r in caplog.records) == 2


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


def test_a_world_that_cannot_start_says_why_with_its_last_log_line(
    launcher: Launcher, caplog: pytest.LogCaptureFixture
) -> None:
    """Before: "the world died 5 times at its start; ending", and nothing of why."""
    caplog.set_level("ERROR", logger="swarm.launcher")
    launcher.children["world"].log_path.write_text("booting\nswarm world: no such thing\n\n")
    for _ in range(WORLD_MAX_QUICK_DEATHS):
        _world(launcher).returncode = 2
        launcher.supervise_world()
    assert [r.getMessage() for r in caplog.records] == [
        f"the world died {WORLD_MAX_QUICK_DEATHS} times at its start; ending (its last log "
        "line: 'swarm world: no such thing')"
    ]


@pytest.mark.parametrize("gone", ["credentials", "folder"])
def test_a_process_whose_run_folder_is_gone_is_not_restarted_and_says_why(
    launcher: Launcher, gone: str
) -> None:
    """Before, with the run folder deleted, `swarm restart robot2` answered ok with a new pid,
    the process ended at once (status 2), and the world was tried five times in vain."""
    out = launcher.plan.out_dir
    if gone == "credentials":
        launcher.credential_files["robot2"].unlink()
        launcher.credential_files["world"].unlink()
    else:
        shutil.rmtree(out)
    before = _process(launcher, "robot2")
    refused = launcher.admin_handlers()["restart"](_request("robot2"))
    assert isinstance(refused, AdminError) and refused.reason == AdminRefusal.CANNOT_START
    assert refused.error.startswith("robot2 cannot start: ")
    if gone == "folder":
        assert f"the run folder {out} is gone (deleted or moved" in refused.error
    else:
        assert "robot2.json is missing (deleted while the run went on)" in refused.error
    assert _process(launcher, "robot2") is before and launcher.children["robot2"].restarts == 0
    _world(launcher).returncode = -9
    assert launcher.supervise_world() == -9  # the run ends at once: no world can start
    assert launcher.children["world"].restarts == 0


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


@pytest.mark.parametrize("name", ["robot1", "world", "router"])
def test_stop_freezes_a_process_and_cont_lets_it_run_on(launcher: Launcher, name: str) -> None:
    handlers = launcher.admin_handlers()
    process = _process(launcher, name)
    assert handlers["stop"](_request(name)) == StopReply(stopped=True)
    assert process.signals == [signal.SIGSTOP]
    assert _status(launcher).processes[name].stopped
    assert _status(launcher).processes[name].running
    assert handlers["cont"](_request(name)) == ContReply(continued=True)
    assert process.signals == [signal.SIGSTOP, signal.SIGCONT]
    status = _status(launcher).processes[name]
    assert not status.stopped and status.running and status.restarts == 0
    assert _process(launcher, name) is process


def test_a_stopped_world_is_not_restarted_by_the_supervisor(launcher: Launcher) -> None:
    world = _world(launcher)
    launcher.admin_handlers()["stop"](_request("world"))
    for _ in range(3):
        assert launcher.supervise_world() is None
    assert _world(launcher) is world and launcher.children["world"].restarts == 0
    assert _status(launcher).processes["world"].stopped


def test_stop_and_cont_of_a_process_that_does_not_run_change_nothing(
    launcher: Launcher,
) -> None:
    handlers = launcher.admin_handlers()
    handlers["kill"](_request("robot2"))
    killed = _process(launcher, "robot2")
    assert handlers["stop"](_request("robot2")) == StopReply(stopped=False)
    assert handlers["cont"](_request("robot2")) == ContReply(continued=False)
    assert killed.signals == []
    status = _status(launcher).processes["robot2"]
    assert status.killed and not status.stopped and not status.running


def test_kill_and_restart_of_a_stopped_process_clear_the_stop(launcher: Launcher) -> None:
    handlers = launcher.admin_handlers()
    handlers["stop"](_request("robot1"))
    restarted = handlers["restart"](_request("robot1"))
    assert isinstance(restarted, RestartReply)
    status = _status(launcher).processes["robot1"]
    assert not status.stopped and status.running and status.restarts == 1
    handlers["stop"](_request("robot2"))
    assert handlers["kill"](_request("robot2")) == KillReply(killed=True)
    assert not _status(launcher).processes["robot2"].stopped


def test_shutdown_continues_a_stopped_process_so_it_sees_its_sigterm(
    launcher: Launcher,
) -> None:
    launcher.admin_handlers()["stop"](_request("robot1"))
    frozen = _process(launcher, "robot1")
    launcher.shutdown(grace_s=0.0)
    assert frozen.signals == [signal.SIGSTOP, signal.SIGTERM, signal.SIGCONT]


def test_shutdown_ends_the_world_before_the_robots_and_the_router_last(tmp_path: Path) -> None:
    factory = StandInFactory()
    plan = LaunchPlan(scenario=PAPER, robots=("robot1", "robot2"), out_dir=tmp_path)
    launcher = Launcher(plan, factory=factory)  # type: ignore[arg-type]
    for name in launcher.children:
        launcher.start(name)
    pid_names = {_process(launcher, name).pid: name for name in launcher.children}
    launcher.shutdown(grace_s=0.0)
    ended = [pid_names[pid] for pid in factory.ended]
    assert ended == ["dashboard", "world", "robot1", "robot2", "router"]


@pytest.mark.parametrize("verb", ["stop", "cont"])
def test_stop_and_cont_of_an_unknown_process_are_refused_and_nothing_changes(
    launcher: Launcher, verb: str
) -> None:
    before = {name: child.process for name, child in launcher.children.items()}
    for body in (b'{"process": "robot9"}', b'{"process": "dashboard"}'):
        reply = launcher.admin_handlers()[verb](body)
        assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNKNOWN_PROCESS
    reply = launcher.admin_handlers()[verb](b'{"robot": "robot1"}')
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.INVALID_REQUEST
    assert {name: child.process for name, child in launcher.children.items()} == before
    for child in launcher.children.values():
        assert child.running and not child.stopped
        assert isinstance(child.process, StandInProcess) and child.process.signals == []


def test_a_router_that_runs_but_never_lets_the_launcher_in_ends_the_start_with_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The stand-in router runs and never listens: the launcher's logins fail as they would
    # against a router that refuses them.
    monkeypatch.setattr(launcher_module, "ROUTER_LOGIN_TIMEOUT_S", 2.0)
    plan = LaunchPlan(
        scenario=PAPER,
        robots=("robot1", "robot2"),
        out_dir=tmp_path,
        dashboard=False,
        endpoint=f"tcp/127.0.0.1:{free_port()}",
    )
    factory = StandInFactory()
    launcher = Launcher(plan, factory=factory)  # type: ignore[arg-type]
    with pytest.raises(LaunchError, match=r"without letting the launcher in .*/router\.log"):
        launcher.up()
    assert [child.pid for child in factory.started] == [factory.started[0].pid]  # only the router
    assert not launcher.children["router"].running  # and it was stopped


@pytest.mark.parametrize(
    ("ports", "named"),
    [
        ({"web_port": 9100, "grpc_port": 9100}, "--web-port and --grpc-port are both 9100"),
        ({"web_port": 7447}, "--port and --web-port are both 7447"),
        ({"grpc_port": 7447}, "--port and --grpc-port are both 7447"),
    ],
)
def test_a_port_given_twice_is_refused_before_anything_is_written(
    tmp_path: Path, ports: dict[str, int], named: str
) -> None:
    # Before, the swarm ran and its dashboard exited at once, after the URL had been printed.
    out = tmp_path / "run"
    plan = LaunchPlan(scenario=PAPER, robots=("robot1",), out_dir=out, **ports)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=named):
        Launcher(plan, factory=StandInFactory())  # type: ignore[arg-type]
    assert not out.exists()
    without_dashboard = LaunchPlan(
        scenario=PAPER,
        robots=("robot1",),
        out_dir=out,
        dashboard=False,
        **ports,  # type: ignore[arg-type]
    )
    without_dashboard.check()

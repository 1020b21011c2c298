"""Stop signals set the stop event without waiting for a lock the interrupted thread holds
(services/stop_signals.py)."""

from __future__ import annotations

import ctypes
import os
import platform
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from services.stop_signals import (
    IGNORED_INTERRUPT_REPORT,
    STOP_SIGNALS,
    StopOnSignal,
    _quiet_about_ignored_interrupts,
)

ROOT = Path(__file__).resolve().parents[2]


def test_a_signal_landing_while_its_thread_holds_the_events_lock_still_stops() -> None:
    """A Python signal handler runs in the thread it interrupts, maybe inside `Event.wait` or
    `Event.set` of the very event it sets, whose lock is not re-entrant; and a second signal
    may interrupt the first handler.  Calling `stop.set()` there waits for ever."""
    stop = threading.Event()
    handler = StopOnSignal(stop)
    returned = threading.Event()

    def interrupted_inside_the_event() -> None:
        with stop._cond:  # the event's own lock, held as inside its wait or set
            handler(signal.SIGTERM, None)
            handler(signal.SIGTERM, None)  # a second signal, nested in the first
        returned.set()

    threading.Thread(target=interrupted_inside_the_event, daemon=True).start()
    assert returned.wait(5), "the handler waited for a lock its own thread holds"
    assert stop.wait(5)
    assert handler.requested


WAITING_CHILD = (
    "import signal, threading, time\n"
    "from services.stop_signals import stop_on_signals, wait_for_stop\n"
    "stop = threading.Event()\n"
    "stop_on_signals(stop)\n"
    "{before_the_wait}"
    "print('waiting', flush=True)\n"
    "wait_for_stop(stop)\n"
    "print('stopped', flush=True)\n"
)
"""A process that waits for its stop the way the router does."""


def _run_waiting_child(before_the_wait: str = "", sig: signal.Signals | None = None) -> None:
    """Run `WAITING_CHILD`, send it `sig` once it waits (if any), and check that it stopped."""
    script = WAITING_CHILD.format(before_the_wait=before_the_wait)
    process = subprocess.Popen(
        [sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout is not None
        assert process.stdout.readline().strip() == "waiting"
        if sig is not None:
            process.send_signal(sig)
        out, _ = process.communicate(timeout=30)
    finally:
        process.kill()
    assert out.strip() == "stopped"
    assert process.returncode == 0


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=[s.name for s in STOP_SIGNALS])
def test_each_stop_signal_ends_a_process_waiting_on_its_event(sig: signal.Signals) -> None:
    _run_waiting_child(sig=sig)


def test_a_stop_signal_that_lands_on_another_thread_still_ends_the_wait() -> None:
    """The kernel gives a process's signal to any thread that does not block it; Python notes
    it there and runs the handler only when the main thread runs Python code again, which an
    untimed `Event.wait` never does."""
    _run_waiting_child(
        "def signal_this_thread():\n"
        "    time.sleep(0.5)  # the main thread is waiting by then\n"
        "    signal.pthread_kill(threading.get_ident(), signal.SIGTERM)\n"
        "    time.sleep(3600)\n"
        "threading.Thread(target=signal_this_thread, daemon=True).start()\n"
    )


TGKILL_SYSCALL = {"x86_64": 234, "aarch64": 131}
"""Linux's tgkill(2) by machine: a signal to one thread of another process."""


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.machine() not in TGKILL_SYSCALL,
    reason="tgkill(2) is Linux's",
)
def test_a_router_ends_on_a_sigterm_that_lands_on_one_of_zenohs_threads() -> None:
    """What a killed launcher's parent-death SIGTERM can do: land on a thread of Zenoh's."""
    with subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "router",
            "--listen",
            f"tcp/127.0.0.1:{_free_port()}",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    ) as router:
        try:
            assert router.stdout is not None
            assert router.stdout.readline().startswith("router listening")
            threads = [int(tid) for tid in os.listdir(f"/proc/{router.pid}/task")]
            zenoh_threads = [tid for tid in threads if tid != router.pid]
            assert zenoh_threads, "the router runs no thread beside its main one"
            libc = ctypes.CDLL(None, use_errno=True)
            sent = libc.syscall(
                TGKILL_SYSCALL[platform.machine()], router.pid, zenoh_threads[0], signal.SIGTERM
            )
            assert sent == 0, os.strerror(ctypes.get_errno())
            assert router.wait(timeout=30) == 0
        finally:
            router.kill()


@pytest.mark.parametrize(
    ("process", "sig"),
    [("robot", signal.SIGINT), ("robot", signal.SIGTERM), ("world", signal.SIGINT)],
)
def test_a_process_waiting_for_its_router_stops_on_a_signal(
    process: str, sig: signal.Signals, tmp_path: Path
) -> None:
    # Before, zenoh.open waited for the router in Rust, deaf to the handlers: a robot or world
    # started before its router, or with a wrong endpoint, ignored Ctrl-C and SIGTERM.
    from swarm_config.credentials import generate_credential_set, write_credential_set

    files = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1",))
    )
    with socket.socket() as unused:  # a port where no router listens
        unused.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{unused.getsockname()[1]}"
    argv = [sys.executable, "-m", "services.cli.main", process, "--connect", endpoint]
    argv += ["--scenario", str(ROOT / "configs" / "scenarios" / "paper.yaml")]
    if process == "robot":
        argv += ["--name", "robot1", "--credentials", str(files["robot1"])]
    else:
        argv += ["--out", str(tmp_path / "run"), "--credentials", str(files["world"])]
    child = subprocess.Popen(
        argv,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        # It waits once its log says nothing more for a while; give it time to get there.
        with pytest.raises(subprocess.TimeoutExpired):
            child.wait(timeout=8)
        child.send_signal(sig)
        output, _ = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0, output
    assert "stopped before a router let" in output, output
    assert "Traceback" not in output


def _unraisable(value: BaseException) -> SimpleNamespace:
    return SimpleNamespace(
        exc_type=type(value), exc_value=value, exc_traceback=None, err_msg=None, object=None
    )


def test_a_ctrl_c_ignored_by_a_race_is_not_reported_and_every_other_report_is() -> None:
    """CI once saw `swarm tune`, Ctrl-C pressed again and again, print CPython's traceback of
    "OSError: Signal 2 ignored due to race condition": a SIGINT landed while the first one's
    handler set SIGINT to SIG_IGN.  That report is dropped; any other goes on as before."""
    passed_on: list[SimpleNamespace] = []
    hook = _quiet_about_ignored_interrupts(passed_on.append)
    hook(_unraisable(OSError(IGNORED_INTERRUPT_REPORT)))
    assert passed_on == []
    others = [
        OSError("Signal 15 ignored due to race condition"),
        OSError(28, "No space left on device"),
        RuntimeError(IGNORED_INTERRUPT_REPORT),
    ]
    for value in others:
        hook(_unraisable(value))
    assert [report.exc_value for report in passed_on] == others


def test_interrupt_once_installs_the_quiet_hook_in_front_of_the_one_before() -> None:
    code = (
        "import sys\n"
        "from services.stop_signals import interrupt_once\n"
        "before = sys.unraisablehook\n"
        "interrupt_once()\n"
        "print(sys.unraisablehook is not before, sys.unraisablehook.__qualname__)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        # as from a terminal: a shell's background job starts with SIGINT ignored, which
        # interrupt_once leaves as it is
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert result.stdout.split() == ["True", "_quiet_about_ignored_interrupts.<locals>.hook"]

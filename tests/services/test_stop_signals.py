"""Stop signals set the stop event without waiting for a lock the interrupted thread holds
(services/stop_signals.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from services.stop_signals import STOP_SIGNALS, StopOnSignal

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


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=[s.name for s in STOP_SIGNALS])
def test_each_stop_signal_ends_a_process_waiting_on_its_event(sig: signal.Signals) -> None:
    waiting = (
        "import threading\n"
        "from services.stop_signals import stop_on_signals\n"
        "stop = threading.Event()\n"
        "stop_on_signals(stop)\n"
        "print('waiting', flush=True)\n"
        "stop.wait()\n"
        "print('stopped', flush=True)\n"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", waiting], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout is not None
        assert process.stdout.readline().strip() == "waiting"
        process.send_signal(sig)
        out, _ = process.communicate(timeout=30)
    finally:
        process.kill()
    assert out.strip() == "stopped"
    assert process.returncode == 0

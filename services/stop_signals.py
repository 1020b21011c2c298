"""Stop a process's main loop on SIGTERM, SIGINT or SIGHUP without a deadlock.

Every long-running process of the swarm (router, world, robots, dashboard, launcher) runs until
a `threading.Event` is set, and used to set it straight from its signal handler.  A Python signal
handler runs in the main thread between two bytecodes of whatever that thread was doing, and a
second signal can interrupt the first handler.  `Event.set` takes the event's lock, which is not
re-entrant: a handler that interrupts a `set` or a `wait` of the same event while it holds that
lock waits for itself for ever.  Several SIGTERMs in a row are what a child of `swarm up` gets
when the launcher is killed outright: the kernel sends the parent-death signal
(services/launcher/orphans.py) each time the child is handed from one exiting thread of the
launcher to the next, and a router so stopped was seen stuck in three nested handlers, ignoring
every later SIGTERM.

So the handler only notes the request (a plain attribute, no lock) and hands the `set` to a
short thread of its own, which takes the lock once the main thread lets go of it; further
signals find the request noted and return at once.

The kernel hands a process's signal to any one of its threads that does not block it, Zenoh's
own threads included.  Python then only notes it there, and its handler runs when the main
thread next runs Python code.  A main thread asleep in an untimed `Event.wait` does not: a
router so waiting was seen to outlive its killed launcher, its parent-death SIGTERM noted and
never handled.  So a main thread with nothing else to do waits in `wait_for_stop`, which comes
back to Python every `STOP_POLL_S`.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Iterable
from types import FrameType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sys import UnraisableHookArgs

STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
"""SIGHUP too: the terminal of `swarm up` closed; stop as for Ctrl-C rather than vanish."""
STOP_POLL_S = 0.2
"""How often a main thread waiting for a stop runs the signal handlers other threads noted."""
EXIT_INTERRUPTED = 130
"""A command stopped by Ctrl-C (128 + SIGINT, as a shell reports it)."""


class StopOnSignal:
    """A signal handler that sets `stop` once, from a thread of its own (module docstring)."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self.requested = False
        """A stop signal came (set by the first; later ones change nothing)."""
        self.signum: int | None = None
        """The first stop signal's number, None while none came."""

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            return
        self.requested = True
        self.signum = signum
        threading.Thread(target=self.stop.set, name="stop-signal", daemon=True).start()


def stop_on_signals(
    stop: threading.Event, signals: Iterable[signal.Signals] = STOP_SIGNALS
) -> StopOnSignal:
    """Install a `StopOnSignal` for `stop` as the handler of each of `signals`."""
    handler = StopOnSignal(stop)
    for sig in signals:
        signal.signal(sig, handler)
    return handler


def wait_for_stop(stop: threading.Event, poll_s: float = STOP_POLL_S) -> None:
    """Wait in the main thread until `stop` is set, running every `poll_s` the handlers of
    signals that landed on another thread (module docstring)."""
    while not stop.wait(poll_s):
        pass


IGNORED_INTERRUPT_REPORT = f"Signal {int(signal.SIGINT)} ignored due to race condition"
"""What CPython reports, as an exception it cannot raise, for a SIGINT that landed while its
handler was being set to SIG_IGN: a later Ctrl-C that `interrupt_once` means to ignore."""


def _interrupt_once(_signum: int, _frame: FrameType | None) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _quiet_about_ignored_interrupts(
    previous: Callable[[UnraisableHookArgs], object],
) -> Callable[[UnraisableHookArgs], None]:
    """An unraisable hook that drops CPython's report of a SIGINT ignored by a race (Ctrl-C
    pressed again while `_interrupt_once` sets SIG_IGN: a traceback on the terminal for a
    keypress meant to do nothing) and hands every other report to `previous`."""

    def hook(unraisable: UnraisableHookArgs) -> None:
        value = unraisable.exc_value
        if isinstance(value, OSError) and str(value) == IGNORED_INTERRUPT_REPORT:
            return
        previous(unraisable)

    return hook


def interrupt_once() -> None:
    """Ctrl-C raises KeyboardInterrupt once in a command's process; later ones are ignored.

    A command that handles its Ctrl-C then only winds down: `swarm tune` says where its
    checkpoint is, the batch simulator's worker threads finish the step they are in (about a
    second at most) before the interpreter exits.  A second Ctrl-C used to interrupt that,
    with a traceback from Python's exit or with the tuner's message lost.  SIGTERM and SIGKILL
    still end the process; a SIGINT the process was started ignoring stays ignored; a command
    that installs its own stop handlers (`stop_on_signals`) replaces this one.  A Ctrl-C that
    lands while the handler is being set to SIG_IGN is one CPython reports on stderr, as a
    traceback of an exception it cannot raise: that report is dropped
    (`_quiet_about_ignored_interrupts`)."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        sys.unraisablehook = _quiet_about_ignored_interrupts(sys.unraisablehook)
        signal.signal(signal.SIGINT, _interrupt_once)

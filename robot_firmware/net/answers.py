"""Admin answers that do not come at once, on either side of a request.

* `DeferredAnswer`: a handler's answer given later.  The world forwards a register fault to the
  robot, or a process fault to the launcher; in real time it must not hold its loop while that
  process answers (a frozen robot would stop every robot's sense messages), so its `fault`
  handler returns a `DeferredAnswer`, and the admin queue (robot_firmware/net/admin.py) keeps
  the query until the world completes it.
* `PendingAnswer`: the forward itself, a request sent without waiting, looked at from the
  owner's loop until its answer comes, the request ends without one, or its time-out passes.

No transport here: the world's Zenoh callbacks feed a `PendingAnswer`, so the fault hub
(world/faults.py) stays free of the network.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from pydantic import BaseModel


class DeferredAnswer:
    """An admin answer that a handler gives later (module docstring): `serve` binds the query's
    sender, the handler's owner calls `complete` once, from the same loop."""

    def __init__(self) -> None:
        self._send: Callable[[BaseModel], None] | None = None
        self._answer: BaseModel | None = None

    def bind(self, send: Callable[[BaseModel], None]) -> None:
        """Where the answer goes (at once, if it is already known)."""
        if self._answer is not None:
            send(self._answer)
        else:
            self._send = send

    def complete(self, answer: BaseModel) -> None:
        """The answer: sent if a query waits for it, kept otherwise (a campaign's fault)."""
        self._answer = answer
        send, self._send = self._send, None
        if send is not None:
            send(answer)

    @property
    def answer(self) -> BaseModel | None:
        """The answer, once `complete` gave it."""
        return self._answer


class PendingAnswer:
    """The answer to a request sent without waiting (module docstring).  The transport's
    callbacks set it; the owner's loop reads `result`."""

    def __init__(self, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.sent_s = clock()
        self._give_up_s = self.sent_s + timeout_s + 1.0
        self._payload: bytes | None = None
        self._ended = False

    def on_answer(self, payload: bytes) -> None:
        """An answer came (from a Zenoh callback): the first one counts."""
        if self._payload is None:
            self._payload = payload

    def on_end(self) -> None:
        """Zenoh's end of the request: every answer that will come has come."""
        self._ended = True

    def result(self) -> tuple[bool, bytes | None]:
        """(done, the answer or None): done once an answer came, the request ended without
        one, or its time-out passed by a second without Zenoh ending it."""
        ended = self._ended  # read first: an answer always comes before the end
        payload = self._payload
        if payload is not None:
            return True, payload
        return ended or self._clock() >= self._give_up_s, None

    def waited_s(self) -> float:
        """Seconds since the request was sent."""
        return self._clock() - self.sent_s

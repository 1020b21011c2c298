"""Admin queries (`swarm/<swarm>/admin/<target>/<verb>`): served from the owner's own loop, and
asked from anywhere with `admin_request`.

Zenoh callbacks must not block, so the queryable's callback only queues the query; the process
that owns the state (a robot between control ticks, the world between steps, the launcher)
calls `serve` with one handler per verb.  A handler takes the request body and returns a reply
model of `robot_firmware/net/messages.py`; an unknown verb gets an `AdminError` naming the known
ones, and a handler that fails is answered with an `AdminError` too (logged, never a crash).
`AdminCounters` counts the answers, and the refusals per `AdminRefusal` reason; a handler
refuses a bad request itself, so `handler_failed` (the safety net) stays at zero unless a
handler has a bug.

A handler that cannot answer at once returns a `DeferredAnswer`
(robot_firmware/net/answers.py): `serve` keeps the query and answers it when the handler's owner
calls `complete`.
"""

from __future__ import annotations

import json
import logging
import queue
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import TypeVar

import zenoh
from pydantic import BaseModel

from robot_firmware.net.answers import DeferredAnswer
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import AdminError, AdminRefusal, parse_reply
from robot_firmware.net.request_deadline import (
    expired_request_problem,
    reply_by_unix_ns,
    request_attachment,
)
from robot_firmware.net.session import open_client
from swarm_config.credentials import ProcessCredentials

log = logging.getLogger("swarm.admin")

R = TypeVar("R", bound=BaseModel)


Handler = Callable[[bytes], BaseModel | DeferredAnswer]


@dataclass
class AdminCounters:
    """Admin requests answered by one process, and the refusals among them per reason."""

    answered: int = 0
    refused: Counter[str] = field(default_factory=Counter)

    @property
    def handler_failures(self) -> int:
        """Requests whose handler raised (answered by the safety net of `answer`)."""
        return self.refused[AdminRefusal.HANDLER_FAILED]


ADMIN_QUEUE_MAX = 64
"""Requests that may wait for their owner's loop.  In a flood the callback answers the next
ones at once, refused as `busy` (one ready-made reply), so that neither the queue nor the
loop's work grows with the flood."""
ADMIN_SERVE_BUDGET_S = 0.002
"""The longest one `serve` answers for (it answers at least one request): the rest wait for
the loop's next pass.  A fifth of a control period, so a flood of queries cannot hold a
robot's control tick or the world's step back (before, a loop answered for as long as
requests kept coming: ten seconds of a 10 s flood of `status` queries)."""
_BUSY_REPLY = (
    AdminError(
        error=f"busy: {ADMIN_QUEUE_MAX} admin requests already wait for this process; ask again",
        reason=AdminRefusal.BUSY,
    )
    .model_dump_json()
    .encode()
)


class AdminQueue:
    def __init__(
        self,
        serve_budget_s: float = ADMIN_SERVE_BUDGET_S,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self._queries: queue.SimpleQueue[tuple[zenoh.Query, int]] = queue.SimpleQueue()
        self.counters = AdminCounters()
        self.serve_budget_s = serve_budget_s
        self._clock = clock
        self.serving_reply_by_unix_ns: int | None = None
        """While a handler runs: until when the request's sender waits (its attachment), for
        a handler that passes the request on (robot_firmware/net/request_deadline.py)."""

    def on_query(self, query: zenoh.Query) -> None:
        """The queryable's callback: queue and return, or, when `ADMIN_QUEUE_MAX` requests
        already wait, answer `busy` and return (counted under `refused`, by this thread
        only)."""
        if self._queries.qsize() >= ADMIN_QUEUE_MAX:
            self.counters.refused[AdminRefusal.BUSY] += 1
            query.reply(query.key_expr, _BUSY_REPLY)
            return
        self._queries.put((query, time.time_ns()))

    @property
    def pending(self) -> bool:
        """Whether a query waits (one that comes just after the answer waits for the next
        look)."""
        return not self._queries.empty()

    def serve(self, handlers: Mapping[str, Handler]) -> int:
        """Answer the queued queries for at most `serve_budget_s` (at least one); returns how
        many were answered."""
        served = 0
        deadline = self._clock() + self.serve_budget_s
        while served == 0 or self._clock() < deadline:
            try:
                query, received_unix_ns = self._queries.get_nowait()
            except queue.Empty:
                return served
            verb = SwarmKeys.last_chunk(str(query.key_expr))
            attachment = None if query.attachment is None else query.attachment.to_bytes()
            expired = expired_request_problem(attachment, received_unix_ns, time.time_ns())
            if expired is not None:
                problem, malformed = expired
                log.warning("admin request %r not served: %s", verb, problem)
                reason = AdminRefusal.INVALID_REQUEST if malformed else AdminRefusal.EXPIRED
                reply: BaseModel | DeferredAnswer = AdminError(error=problem, reason=reason)
            else:
                body = query.payload.to_bytes() if query.payload is not None else b""
                self.serving_reply_by_unix_ns = reply_by_unix_ns(attachment)
                try:
                    reply = _reply(handlers, verb, body)
                finally:
                    self.serving_reply_by_unix_ns = None
            if isinstance(reply, DeferredAnswer):
                reply.bind(partial(self._answer_later, query))
            else:
                self._count(reply)
                query.reply(query.key_expr, reply.model_dump_json().encode())
            served += 1
        return served

    def _count(self, reply: BaseModel) -> None:
        count_answer(self.counters, reply)

    def _answer_later(self, query: zenoh.Query, reply: BaseModel) -> None:
        """A `DeferredAnswer` completed: answer the query it kept, and end it."""
        self._count(reply)
        query.reply(query.key_expr, reply.model_dump_json().encode())
        query.drop()


def answer(
    handlers: Mapping[str, Handler],
    verb: str,
    body: bytes,
    counters: AdminCounters | None = None,
) -> BaseModel | DeferredAnswer:
    """The reply to one admin request (pure but for `counters`: what `serve` sends back, or
    the `DeferredAnswer` it keeps the query for)."""
    reply = _reply(handlers, verb, body)
    if counters is not None and not isinstance(reply, DeferredAnswer):
        count_answer(counters, reply)
    return reply


def count_answer(counters: AdminCounters, reply: BaseModel) -> None:
    """One answer sent, into `counters`."""
    counters.answered += 1
    if isinstance(reply, AdminError):
        counters.refused[reply.reason] += 1


def _reply(handlers: Mapping[str, Handler], verb: str, body: bytes) -> BaseModel | DeferredAnswer:
    handler = handlers.get(verb)
    if handler is None:
        return AdminError(
            error=f"unknown admin verb {verb!r}; use {', '.join(sorted(handlers))}",
            reason=AdminRefusal.UNKNOWN_VERB,
        )
    try:
        return handler(body)
    except Exception as exc:  # a bug in a handler must not take the process down
        log.exception("admin verb %r failed", verb)
        return AdminError(
            error=f"{verb} failed inside the process: {type(exc).__name__}: {exc}",
            reason=AdminRefusal.HANDLER_FAILED,
        )


CONNECT_TIMEOUT_S = 5.0
"""How long a one-off request waits for the router to let it in (a loaded machine can take a
second or two; a swarm that is not running never does)."""


class RouterUnreachableError(Exception):
    """No router at the endpoint (the message) let a one-off client in: none runs there, or it
    refused the client's credentials."""


def ask(
    swarm: str,
    endpoint: str,
    target: str,
    verb: str,
    body: BaseModel | bytes | None = None,
    timeout_s: float = 3.0,
    credentials: ProcessCredentials | None = None,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
) -> bytes | None:
    """Send one admin request to a running swarm; the reply's payload, or None when nobody
    answered.  body: a request model, raw bytes (e.g. a parameter file), or None;
    credentials: the operator's (else those of $SWARM_CREDENTIALS_FILE).

    Raises RouterUnreachableError when no router at `endpoint` let the client in within
    `connect_timeout_s` (none is running there, or it refused the credentials)."""
    keys = SwarmKeys(swarm)
    payload = body.model_dump_json().encode() if isinstance(body, BaseModel) else body
    try:
        session = open_client(
            [endpoint],
            credentials=credentials,
            connect_timeout_s=connect_timeout_s,
            zenoh_errors_logged=False,
        )
    except zenoh.ZError:
        raise RouterUnreachableError(endpoint) from None
    with session:
        replies = session.get(
            keys.admin(target, verb),
            payload=payload,
            attachment=request_attachment(timeout_s),
            timeout=timeout_s,
        )
        for reply in replies:
            if reply.ok is not None:
                return bytes(reply.ok.payload.to_bytes())
    return None


def admin_request(
    swarm: str,
    endpoint: str,
    target: str,
    verb: str,
    reply_type: type[R],
    body: BaseModel | bytes | None = None,
    timeout_s: float = 3.0,
    credentials: ProcessCredentials | None = None,
) -> R | AdminError | None:
    """Ask a running swarm's process one admin question: the reply as `reply_type`, an
    `AdminError` when the process refused, or None when nobody answered (no router let the
    client in, or the answer fits neither)."""
    try:
        payload = ask(swarm, endpoint, target, verb, body, timeout_s, credentials)
    except RouterUnreachableError:
        return None
    return None if payload is None else parse_reply(reply_type, payload)


def reply_as_json(payload: bytes) -> dict[str, object] | None:
    """Any admin reply as a JSON object (for printing), None when it is not one."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    return data if isinstance(data, dict) else None

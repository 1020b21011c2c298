"""Admin queries (`swarm/<swarm>/admin/<target>/<verb>`), answered from the owner's own loop.

Zenoh callbacks must not block, so the queryable's callback only queues the query; the process
that owns the state (a robot between control ticks, the world between steps, the launcher)
calls `serve` with one handler per verb.  A handler takes the request body and returns a JSON-able
reply; an unknown verb gets an error reply naming the known ones.
"""

from __future__ import annotations

import json
import queue
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from robot_firmware.net.keys import SwarmKeys

Handler = Callable[[bytes], dict[str, Any]]


class AdminQueue:
    def __init__(self) -> None:
        self._queries: queue.SimpleQueue[zenoh.Query] = queue.SimpleQueue()

    def on_query(self, query: zenoh.Query) -> None:
        """The queryable's callback: queue and return."""
        self._queries.put(query)

    def serve(self, handlers: Mapping[str, Handler]) -> int:
        """Answer every queued query; returns how many were answered."""
        served = 0
        while True:
            try:
                query = self._queries.get_nowait()
            except queue.Empty:
                return served
            verb = SwarmKeys.last_chunk(str(query.key_expr))
            body = query.payload.to_bytes() if query.payload is not None else b""
            handler = handlers.get(verb)
            if handler is None:
                known = ", ".join(sorted(handlers))
                reply: dict[str, Any] = {
                    "ok": False,
                    "error": f"unknown admin verb {verb!r}; use {known}",
                }
            else:
                reply = handler(body)
            query.reply(query.key_expr, json.dumps(reply).encode())
            served += 1

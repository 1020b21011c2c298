"""Admin requests and replies: the typed messages, the verb dispatcher and the `regs` handler,
without a network."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from pydantic import BaseModel

from robot_firmware.fpga.address_map import BRIDGE_BASE
from robot_firmware.fpga.fabric import Fabric
from robot_firmware.net.admin import ADMIN_QUEUE_MAX, AdminQueue, answer, reply_as_json
from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    KillReply,
    MessageDropReason,
    RegsAccessReply,
    RegsBusError,
    RegsDumpReply,
    TelemetryMessage,
    WorldStatusReply,
    parse_message,
    parse_message_or_reason,
    parse_reply,
)
from robot_firmware.net.request_deadline import (
    NS_PER_S,
    TRANSIT_MAX_S,
    machine_id,
    reply_by_unix_ns,
    request_attachment,
)
from robot_firmware.regs_admin import handle_regs_request

ROOT = Path(__file__).resolve().parents[2]

SYSID_ID = BRIDGE_BASE  # the system ID IP sits first in the map
SYSID_SCRATCH = BRIDGE_BASE + 0x10


def test_an_unknown_verb_is_refused_naming_the_known_ones() -> None:
    reply = answer({"status": lambda _b: KillReply(killed=True)}, "reboot", b"")
    assert isinstance(reply, AdminError)
    assert "'reboot'" in reply.error and "status" in reply.error


def test_a_failing_handler_is_answered_with_an_error_not_a_crash() -> None:
    def broken(_body: bytes) -> BaseModel:
        raise ZeroDivisionError("division by zero")

    reply = answer({"status": broken}, "status", b"")
    assert isinstance(reply, AdminError)
    assert "ZeroDivisionError" in reply.error


def test_replies_parse_as_their_model_or_as_a_refusal() -> None:
    ok = KillReply(killed=False).to_json_bytes()
    assert parse_reply(KillReply, ok) == KillReply(killed=False)
    refused = AdminError(error="no robot 'robot9'").to_json_bytes()
    assert parse_reply(KillReply, refused) == AdminError(error="no robot 'robot9'")
    assert parse_reply(KillReply, b"not json") is None
    assert parse_reply(WorldStatusReply, ok) is None  # an ok reply of another verb
    assert reply_as_json(ok) == {"ok": True, "killed": False}
    assert reply_as_json(b"[1, 2]") is None
    nested_too_deep = b"[" * 100_000 + b"]" * 100_000  # json's parser recurses: RecursionError
    assert parse_reply(KillReply, nested_too_deep) is None
    assert reply_as_json(nested_too_deep) is None


def test_telemetry_round_trips_and_tolerates_fields_it_does_not_know() -> None:
    message = TelemetryMessage(
        robot="robot2", t_s=1.5, role="follower", estimate=(1.0, 2.0, 0.5), kp=(1.0, 2.0, 3.0)
    )
    assert parse_message(TelemetryMessage, message.to_json_bytes()) == message
    newer = json.loads(message.to_json_bytes())
    newer["battery_v"] = 11.9
    assert parse_message(TelemetryMessage, json.dumps(newer)) == message
    assert parse_message(TelemetryMessage, b'{"robot": "robot2"}') is None  # no t_s
    assert parse_message(TelemetryMessage, b"\xff\xfe") is None


def test_a_message_is_read_as_json_text_then_validated_would_read_it() -> None:
    """One pass of pydantic-core takes what `json.loads` then `model_validate` took, and gives
    the same reasons for what they refused; only UTF-8 is JSON text."""
    message = TelemetryMessage(
        robot="robot2", t_s=1.5, role="follower", estimate=(1.0, 2.0, 0.5), kp=(1.0, 2.0, 3.0)
    )
    text = message.to_json_bytes()
    assert parse_message_or_reason(TelemetryMessage, text) == TelemetryMessage.model_validate(
        json.loads(text)
    )
    refused = {
        b"{not json": MessageDropReason.NOT_JSON,
        b"": MessageDropReason.NOT_JSON,
        b"[1, 2]": MessageDropReason.DOES_NOT_FIT,
        text.replace(b'"t_s":1.5', b'"t_s":NaN'): MessageDropReason.DOES_NOT_FIT,
        text.replace(b'"t_s":1.5', b'"t_s":"soon"'): MessageDropReason.DOES_NOT_FIT,
        text.decode().encode("utf-16"): MessageDropReason.NOT_JSON,
    }
    for payload, reason in refused.items():
        assert payload != text
        assert parse_message_or_reason(TelemetryMessage, payload) is reason, payload


def regs(fabric: Fabric, body: object) -> BaseModel:
    payload = body if isinstance(body, bytes) else json.dumps(body).encode()
    return handle_regs_request(fabric.bus, payload)


def test_regs_dump_lists_every_register_by_name() -> None:
    fabric = Fabric()
    dump = regs(fabric, b"")
    assert isinstance(dump, RegsDumpReply)
    first = dump.registers[0]
    assert (first.address, first.peripheral, first.name) == (SYSID_ID, "sysid", "ID")
    assert first.value == 0x5357_524D
    assert len({row.address for row in dump.registers}) == len(dump.registers)


def test_regs_read_and_write_are_real_bus_accesses() -> None:
    fabric = Fabric()
    written = regs(fabric, {"op": "write", "address": SYSID_SCRATCH, "value": 0xCAFE})
    assert written == RegsAccessReply(address=SYSID_SCRATCH, value=0xCAFE, name="sysid.SCRATCH")
    read = regs(fabric, {"op": "read", "address": SYSID_SCRATCH})
    assert isinstance(read, RegsAccessReply) and read.value == 0xCAFE


def test_a_refused_access_is_a_bus_error_and_changes_nothing() -> None:
    fabric = Fabric()
    before = regs(fabric, {"op": "read", "address": SYSID_ID})
    refused = regs(fabric, {"op": "write", "address": SYSID_ID, "value": 0})
    assert isinstance(refused, RegsBusError) and "bus error" in refused.error
    assert regs(fabric, {"op": "read", "address": SYSID_ID}) == before
    unmapped = regs(fabric, {"op": "read", "address": BRIDGE_BASE + 0xF_FF00})
    assert isinstance(unmapped, RegsBusError)


def test_malformed_regs_requests_are_refused_with_the_field_named() -> None:
    fabric = Fabric()
    for body, words in [
        (b"{not json", "invalid regs request"),
        ({"op": "poke", "address": SYSID_ID}, "op"),
        ({"op": "read"}, "needs an 'address'"),
        ({"op": "write", "address": SYSID_SCRATCH}, "needs a 'value'"),
        ({"op": "read", "address": -4}, "address"),
        ({"op": "read", "address": "0xFF200000"}, "address"),
        ({"op": "write", "address": SYSID_SCRATCH, "value": True}, "value"),
        ({"op": "write", "address": SYSID_SCRATCH, "value": 2**40}, "value"),
        ({"op": "read", "address": SYSID_ID, "force": True}, "force"),
    ]:
        reply = regs(fabric, body)
        assert isinstance(reply, AdminError), body
        assert words in reply.error, (body, reply.error)
    assert regs(fabric, {"op": "read", "address": SYSID_SCRATCH}) == RegsAccessReply(
        address=SYSID_SCRATCH, value=0, name="sysid.SCRATCH"
    )


class _BytesStandIn:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _QueryStandIn:
    """What `AdminQueue.serve` reads of a zenoh query, and the reply it sends."""

    def __init__(self, verb: str, attachment: bytes | None = None) -> None:
        self.key_expr = f"swarm/lab/admin/robot1/{verb}"
        self.payload = None
        self.attachment = None if attachment is None else _BytesStandIn(attachment)
        self.replies: list[bytes] = []

    def reply(self, _key_expr: object, payload: bytes) -> None:
        self.replies.append(payload)


def test_the_admin_queue_says_when_a_query_waits_and_serves_it_once() -> None:
    admin = AdminQueue()
    assert not admin.pending
    query = _QueryStandIn("status")
    admin.on_query(query)  # type: ignore[arg-type]
    assert admin.pending
    calls: list[bytes] = []

    def status(body: bytes) -> AdminError:
        calls.append(body)
        return AdminError(error="stand-in")

    assert admin.serve({"status": status}) == 1
    assert calls == [b""]
    assert len(query.replies) == 1 and b"stand-in" in query.replies[0]
    assert not admin.pending
    assert admin.serve({"status": status}) == 0


class _TickingClock:
    """A clock that moves `step_s` on every reading: a query costs one step to answer."""

    def __init__(self, step_s: float) -> None:
        self.now_s = 0.0
        self.step_s = step_s

    def __call__(self) -> float:
        self.now_s += self.step_s
        return self.now_s


def test_one_serve_answers_for_its_time_budget_and_leaves_the_rest_for_the_next_pass() -> None:
    admin = AdminQueue(serve_budget_s=0.0025, clock=_TickingClock(0.001))
    queries = [_QueryStandIn("status") for _ in range(10)]
    for query in queries:
        admin.on_query(query)  # type: ignore[arg-type]
    handlers = {"status": lambda _body: KillReply(killed=False)}
    # The deadline is read at 1 ms (3.5 ms); the first query is answered unread, the next
    # ones while a reading (2, 3, then 4 ms) is before it.
    assert admin.serve(handlers) == 3
    assert [len(q.replies) for q in queries] == [1, 1, 1] + [0] * 7
    assert admin.pending
    served = [admin.serve(handlers) for _ in range(4)]
    assert served == [3, 3, 1, 0] and not admin.pending
    assert all(len(q.replies) == 1 for q in queries)  # each answered once, in order


def test_a_serve_with_no_budget_still_answers_one_query() -> None:
    admin = AdminQueue(serve_budget_s=0.0, clock=_TickingClock(1.0))
    for _ in range(3):
        admin.on_query(_QueryStandIn("status"))  # type: ignore[arg-type]
    handlers = {"status": lambda _body: KillReply(killed=False)}
    assert [admin.serve(handlers) for _ in range(4)] == [1, 1, 1, 0]


def test_a_flood_beyond_the_queue_is_answered_busy_at_once_and_not_queued() -> None:
    admin = AdminQueue()
    waiting = [_QueryStandIn("status") for _ in range(ADMIN_QUEUE_MAX)]
    for query in waiting:
        admin.on_query(query)  # type: ignore[arg-type]
    flood = [_QueryStandIn("status") for _ in range(5)]
    for query in flood:
        admin.on_query(query)  # type: ignore[arg-type]
    for query in flood:
        assert len(query.replies) == 1
        reply = parse_reply(KillReply, query.replies[0])
        assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.BUSY
    assert admin.counters.refused[AdminRefusal.BUSY] == len(flood)
    assert all(not query.replies for query in waiting)
    admin.serve({"status": lambda _body: KillReply(killed=False)})
    late = _QueryStandIn("status")
    admin.on_query(late)  # type: ignore[arg-type]
    assert not late.replies  # room again: queued, not refused


def _served(attachment: bytes | None) -> tuple[list[int | None], AdminError | None, AdminQueue]:
    """Serve one `status` query with `attachment`: the deadlines its handler saw, and the
    refusal it got instead, if any."""
    admin = AdminQueue()
    query = _QueryStandIn("status", attachment)
    admin.on_query(query)  # type: ignore[arg-type]
    seen: list[int | None] = []

    def status(_body: bytes) -> KillReply:
        seen.append(admin.serving_reply_by_unix_ns)
        return KillReply(killed=False)

    admin.serve({"status": status})
    reply = parse_reply(KillReply, query.replies[0])
    return seen, reply if isinstance(reply, AdminError) else None, admin


def test_a_request_within_its_deadline_is_served_and_its_handler_sees_the_deadline() -> None:
    attachment = request_attachment(3.0)
    seen, refusal, admin = _served(attachment)
    assert refusal is None and seen == [reply_by_unix_ns(attachment)]
    assert admin.serving_reply_by_unix_ns is None  # only while the handler runs
    assert _served(None)[:2] == ([None], None)  # a request of another tool: as before


def test_a_request_its_sender_stopped_waiting_for_is_not_carried_out() -> None:
    """Before, a request that waited in a stopped process was carried out once it continued,
    after its sender had printed "no answer"."""
    long_ago = time.time_ns() - 10 * NS_PER_S
    late = request_attachment(3.0, now_unix_ns=long_ago).replace(
        str(long_ago).encode(), str(time.time_ns()).encode(), 1
    )  # sent just now, but its deadline passed 7 s ago
    seen, refusal, admin = _served(late)
    assert seen == [] and refusal is not None and refusal.reason == AdminRefusal.EXPIRED
    assert "stopped waiting" in refusal.error
    assert admin.counters.refused[AdminRefusal.EXPIRED] == 1


def test_a_request_that_came_after_the_session_lease_is_not_carried_out() -> None:
    """The router closes a frozen process's session after the lease (1 s), which ends the
    request at its sender; the request, already in the process's socket, came in once it
    continued.  Before, it was carried out."""
    sent_long_ago = request_attachment(60.0, now_unix_ns=time.time_ns() - 5 * NS_PER_S)
    seen, refusal, _admin = _served(sent_long_ago)
    assert seen == [] and refusal is not None and refusal.reason == AdminRefusal.EXPIRED
    assert "came 5." in refusal.error


@pytest.mark.parametrize(
    "attachment", [b"", b"garbage", b"sent_unix_ns=1;reply_by_unix_ns=-2", b"x" * 10_000]
)
def test_a_malformed_attachment_is_an_invalid_request(attachment: bytes) -> None:
    seen, refusal, _admin = _served(attachment)
    assert seen == [] and refusal is not None
    assert refusal.reason == AdminRefusal.INVALID_REQUEST and len(refusal.error) < 200


def test_the_transit_bound_is_the_clients_session_lease() -> None:
    config = (ROOT / "configs" / "zenoh" / "client.json5").read_text()
    assert f"lease: {round(TRANSIT_MAX_S * 1000)}" in config


def test_a_request_from_another_machine_is_served_whatever_its_clock_says() -> None:
    """The swarm needs no clock synchronisation between hosts (docs/multi-host.md): times from
    another machine's clock are not compared with this one's."""
    ages_ago = request_attachment(3.0, now_unix_ns=time.time_ns() - 3600 * NS_PER_S)
    elsewhere = ages_ago.replace(machine_id().encode(), b"another-host")
    seen, refusal, _admin = _served(elsewhere)
    assert refusal is None and seen == [None]
    assert _served(ages_ago)[1] is not None  # the same times from this machine: refused

"""`devmem` for an emulated robot: register reads, writes and dumps asked over the admin channel.

A request is a `RegsRequest` (robot_firmware/net/messages.py), JSON:

    {"op": "dump"} (or an empty body)            every register by name, stored bits, no side effect
    {"op": "read", "address": 4280289280}        one real bus read (side effects as on hardware)
    {"op": "write", "address": ..., "value": ...} one real bus write

The reply is a `RegsDumpReply` or `RegsAccessReply`, a `RegsBusError` for a refused access (the
bus error it is; it changes nothing) or an `AdminError` for a malformed request.  Requests are
served between control ticks, so a write lands exactly as a driver's would.
"""

from __future__ import annotations

from pydantic import ValidationError

from robot_firmware.fpga.bus import Bus
from robot_firmware.net.messages import (
    AdminError,
    RegisterRow,
    RegsAccessReply,
    RegsBusError,
    RegsDumpReply,
    RegsReply,
    RegsRequest,
    refusal_of,
)
from swarm_config.settings import describe_validation_error


def handle_regs_request(bus: Bus, payload: bytes) -> RegsReply:
    try:
        request = RegsRequest.model_validate_json(payload) if payload else RegsRequest()
    except ValidationError as exc:
        return AdminError(
            error=describe_validation_error("invalid regs request", exc), reason=refusal_of(exc)
        )
    if request.op == "dump":
        return RegsDumpReply(
            registers=tuple(
                RegisterRow(
                    address=base + reg.offset,
                    peripheral=peripheral.name,
                    name=reg.name,
                    access=reg.access.name,
                    value=peripheral.peek(reg.offset),
                )
                for base, peripheral in bus.mapped()
                for reg in peripheral.registers
            )
        )
    address = request.address
    if address is None:
        return AdminError(error=f"invalid regs request: {request.op} needs an 'address'")
    if request.op == "read":
        result = bus.read(address)
        if result.error is not None:
            return RegsBusError(error=f"bus error: {result.error.value}", address=address)
        return RegsAccessReply(address=address, value=result.value, name=_name(bus, address))
    if request.value is None:
        return AdminError(error="invalid regs request: write needs a 'value'")
    result = bus.write(address, request.value)
    if result.error is not None:
        return RegsBusError(error=f"bus error: {result.error.value}", address=address)
    return RegsAccessReply(address=address, value=request.value, name=_name(bus, address))


def _name(bus: Bus, address: int) -> str | None:
    found = bus.decode(address)
    return None if found is None else f"{found.peripheral.name}.{found.register.name}"

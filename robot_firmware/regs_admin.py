"""`devmem` for an emulated robot: register reads, writes and dumps asked over the admin channel.

Requests and replies are JSON.  A request is one of

    {"op": "dump"}                               every register by name, stored bits, no side effect
    {"op": "read", "address": 4280289280}        one real bus read (side effects as on hardware)
    {"op": "write", "address": ..., "value": ...} one real bus write

A reply is {"ok": true, ...} or {"ok": false, "error": "..."}; a refused access is reported as
the bus error it is and changes nothing.  Requests are served between control ticks, so a
write lands exactly as a driver's would.
"""

from __future__ import annotations

import json
from typing import Any

from robot_firmware.fpga.bus import Bus


def handle_regs_request(bus: Bus, payload: bytes) -> dict[str, Any]:
    try:
        request = json.loads(payload.decode("utf-8")) if payload else {"op": "dump"}
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        return {"ok": False, "error": f"request is not JSON: {exc}"}
    if not isinstance(request, dict):
        return {"ok": False, "error": "request must be a JSON object"}
    op = request.get("op", "dump")
    if op == "dump":
        rows = []
        for base, peripheral in bus.mapped():
            for reg in peripheral.registers:
                rows.append(
                    {
                        "address": base + reg.offset,
                        "peripheral": peripheral.name,
                        "register": reg.name,
                        "access": reg.access.name,
                        "value": peripheral.peek(reg.offset),
                    }
                )
        return {"ok": True, "registers": rows}
    address = request.get("address")
    if not isinstance(address, int) or isinstance(address, bool):
        return {"ok": False, "error": "'address' must be an integer"}
    if op == "read":
        result = bus.read(address)
        if result.error is not None:
            return {"ok": False, "error": f"bus error: {result.error.value}", "address": address}
        return {"ok": True, "address": address, "value": result.value, "name": _name(bus, address)}
    if op == "write":
        value = request.get("value")
        if not isinstance(value, int) or isinstance(value, bool):
            return {"ok": False, "error": "'value' must be an integer"}
        result = bus.write(address, value)
        if result.error is not None:
            return {"ok": False, "error": f"bus error: {result.error.value}", "address": address}
        return {"ok": True, "address": address, "value": value, "name": _name(bus, address)}
    return {"ok": False, "error": f"unknown op {op!r}; use dump, read or write"}


def _name(bus: Bus, address: int) -> str | None:
    found = bus.decode(address)
    return None if found is None else f"{found.peripheral.name}.{found.register.name}"

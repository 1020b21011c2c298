"""A driver's window on the bus: 32-bit reads and writes whose refusals are counted, not raised.

The bus reports a refused access (unmapped, misaligned, wrong access kind) as a
`BusResult` with `error` set; it never raises. `RegisterPort` turns that result into
the shape a driver wants, `int | None` for a read and `bool` for a write, and counts
every refusal in `errors`, so each driver can report its own `bus_errors` while the
bus keeps the per-kind totals and the log.
"""

from __future__ import annotations

from robot_firmware.fpga.bus import Bus


class RegisterPort:
    """32-bit register access on behalf of one driver."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.errors = 0

    def read(self, address: int) -> int | None:
        """The word at `address`, or None (counted) when the bus refuses the read."""
        word = self.bus.read_word(address)
        if word is None:
            self.errors += 1
        return word

    def write(self, address: int, value: int) -> bool:
        """Write `value` to `address`; False (counted) when the bus refuses the write."""
        if self.bus.write_word(address, value):
            return True
        self.errors += 1
        return False

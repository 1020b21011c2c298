"""The HPS-to-FPGA bus: 32-bit reads and writes by absolute address, dispatched to peripherals.

Error handling: the bus never raises on a bad access. `read` and `write` return a
`BusResult`; a bad access (unmapped, misaligned, write to a read-only register, read
of a write-only register, value outside 0..2**32-1) comes back with `error` set and
`value` 0 for reads, changes no register, is counted per kind in `error_counts`, and
is logged: at WARNING the 1st, 10th, 100th... time for each kind, at DEBUG otherwise.
A driver checks `result.ok` (or `result.error`) as a real driver would check a bus
fault status, and the firmware loop carries on.

Checks run in this order: address is an integer and word aligned, address decodes to
a declared register, the value fits 32 bits (writes), the access kind allows the
operation. The first failing check names the error.

`read_word` and `write_word` are the drivers' form of the same accesses: the value (or
whether the write went through) instead of a `BusResult`, None or False when refused, with
the same checks, counts, side effects and log.  Each absolute address that passed every check
once is remembered with its peripheral and register offset (until the next `map`), so the
firmware's own accesses to the same few dozen words skip the decoding; anything else takes
the full path of `read` and `write`.  A subclass that overrides `read` or `write` (such as
`RecordingBus`, which keeps every access in order for driver tests) gets word accesses that
go through its overrides.
"""

from __future__ import annotations

import enum
import logging
import operator
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from mypy_extensions import mypyc_attr

from robot_firmware.fpga.address_map import WINDOW_BYTES
from robot_firmware.fpga.registers import WORD_BYTES, WORD_MASK, Peripheral, Register

logger = logging.getLogger(__name__)


class BusErrorKind(enum.Enum):
    """Why an access was refused."""

    UNMAPPED = "unmapped"
    MISALIGNED = "misaligned"
    WRITE_TO_READ_ONLY = "write_to_read_only"
    READ_OF_WRITE_ONLY = "read_of_write_only"
    VALUE_OUT_OF_RANGE = "value_out_of_range"


class BusOp(enum.Enum):
    """Direction of a bus access."""

    READ = "read"
    WRITE = "write"


@dataclass(frozen=True, slots=True)
class BusResult:
    """Outcome of one access: the value read (0 on error) or written, and the error if any."""

    value: int
    error: BusErrorKind | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass(frozen=True, slots=True)
class BusAccess:
    """One recorded access, its address and value as the processor gave them."""

    op: BusOp
    address: Any
    value: Any
    error: BusErrorKind | None = None


@dataclass(frozen=True, slots=True)
class Decoded:
    """An address resolved to its peripheral and register."""

    base: int
    peripheral: Peripheral
    register: Register


@mypyc_attr(allow_interpreted_subclasses=True)
class Bus:
    """Maps peripherals at base addresses and dispatches 32-bit accesses to them."""

    def __init__(self, window_bytes: int = WINDOW_BYTES) -> None:
        if window_bytes <= 0 or window_bytes % WORD_BYTES:
            raise ValueError(f"window of {window_bytes} bytes is not a whole number of words")
        self.window_bytes = window_bytes
        self._windows: dict[int, Peripheral] = {}
        self._errors: Counter[BusErrorKind] = Counter()
        self.read_count = 0
        self.write_count = 0
        self._readable: dict[int, tuple[Peripheral, int]] = {}
        """Word-aligned int addresses of readable registers seen so far (`read_word`)."""
        self._writable: dict[int, tuple[Peripheral, int]] = {}
        """Word-aligned int addresses of writable registers seen so far (`write_word`)."""

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if cls.read is not Bus.read and cls.read_word is Bus.read_word:
            cls.read_word = Bus._read_word_via_read  # type: ignore[method-assign]
        if cls.write is not Bus.write and cls.write_word is Bus.write_word:
            cls.write_word = Bus._write_word_via_write  # type: ignore[method-assign]

    # -- map -------------------------------------------------------------------------

    def map(self, base: int, peripheral: Peripheral) -> None:
        """Place `peripheral` in the window starting at `base`."""
        if base < 0 or base % self.window_bytes:
            raise ValueError(f"base {base:#x} is not aligned to {self.window_bytes:#x}")
        if base in self._windows:
            raise ValueError(f"{base:#x} already holds {self._windows[base].name}")
        if any(p is peripheral for p in self._windows.values()):
            raise ValueError(f"{peripheral.name} is already mapped")
        self._windows[base] = peripheral
        self._readable.clear()
        self._writable.clear()

    def mapped(self) -> tuple[tuple[int, Peripheral], ...]:
        """(base, peripheral) pairs in address order."""
        return tuple(sorted(self._windows.items(), key=lambda item: item[0]))

    def base_of(self, peripheral_name: str) -> int:
        """Base address of the peripheral instance called `peripheral_name`."""
        for base, peripheral in self._windows.items():
            if peripheral.name == peripheral_name:
                return base
        raise KeyError(f"no peripheral called {peripheral_name}")

    def address_of(self, peripheral_name: str, register_name: str) -> int:
        """Absolute address of a register of a mapped peripheral instance."""
        base = self.base_of(peripheral_name)
        return base + self._windows[base].register(register_name).offset

    def decode(self, address: int) -> Decoded | None:
        """The register at `address`, or None when nothing is declared there."""
        if address % WORD_BYTES:
            return None
        offset = address % self.window_bytes
        peripheral = self._windows.get(address - offset)
        if peripheral is None:
            return None
        register = peripheral.register_at(offset)
        if register is None:
            return None
        return Decoded(address - offset, peripheral, register)

    # -- processor side --------------------------------------------------------------

    def read(self, address: object) -> BusResult:
        """Read the 32-bit register at `address` (anything but an integer is a bus error)."""
        self.read_count += 1
        found = self._locate(BusOp.READ, address, 0)
        if isinstance(found, BusResult):
            return found
        if not found.register.access.readable:
            return self._refuse(BusOp.READ, address, 0, BusErrorKind.READ_OF_WRITE_ONLY)
        return BusResult(found.peripheral.read(found.register.offset))

    def write(self, address: object, value: object) -> BusResult:
        """Write the 32-bit `value` to the register at `address` (anything but integers is a
        bus error)."""
        self.write_count += 1
        found = self._locate(BusOp.WRITE, address, value)
        if isinstance(found, BusResult):
            return found
        word = _as_int(value)
        if word is None:
            return self._refuse(BusOp.WRITE, address, value, BusErrorKind.VALUE_OUT_OF_RANGE)
        if not 0 <= word <= WORD_MASK:
            return self._refuse(BusOp.WRITE, address, word, BusErrorKind.VALUE_OUT_OF_RANGE)
        if not found.register.access.writable:
            return self._refuse(BusOp.WRITE, address, word, BusErrorKind.WRITE_TO_READ_ONLY)
        found.peripheral.write(found.register.offset, word)
        return BusResult(word)

    def read_word(self, address: object) -> int | None:
        """As `read`: the word read, or None when the access is refused (counted, logged)."""
        if type(address) is int:
            known = self._readable.get(address)
            if known is not None:
                self.read_count += 1
                peripheral, offset = known
                return peripheral.read(offset)
        result = self.read(address)
        if result.error is not None:
            return None
        if type(address) is int:
            found = self.decode(address)
            if found is not None:
                self._readable[address] = (found.peripheral, found.register.offset)
        return result.value

    def write_word(self, address: object, value: object) -> bool:
        """As `write`: whether the write went through (False: refused, counted, logged)."""
        if type(address) is int and type(value) is int and 0 <= value <= WORD_MASK:
            known = self._writable.get(address)
            if known is not None:
                self.write_count += 1
                peripheral, offset = known
                peripheral.write(offset, value)
                return True
        if self.write(address, value).error is not None:
            return False
        if type(address) is int:
            found = self.decode(address)
            if found is not None:
                self._writable[address] = (found.peripheral, found.register.offset)
        return True

    def _read_word_via_read(self, address: object) -> int | None:
        result = self.read(address)
        return None if result.error is not None else result.value

    def _write_word_via_write(self, address: object, value: object) -> bool:
        return self.write(address, value).error is None

    # -- introspection ---------------------------------------------------------------

    @property
    def error_counts(self) -> Mapping[BusErrorKind, int]:
        """Refused accesses so far, per kind (every kind present, zero if none)."""
        return {kind: self._errors[kind] for kind in BusErrorKind}

    @property
    def error_total(self) -> int:
        return sum(self._errors.values())

    def peek(self, address: int) -> int | None:
        """Stored bits at `address` with no side effect and no counting; None if unmapped."""
        found = self.decode(address)
        if found is None:
            return None
        return found.peripheral.peek(found.register.offset)

    def snapshot(self) -> dict[int, int]:
        """Stored bits of every mapped register, by absolute address, without side effects."""
        return {
            base + reg.offset: peripheral.peek(reg.offset)
            for base, peripheral in self.mapped()
            for reg in peripheral.registers
        }

    # -- internals -------------------------------------------------------------------

    def _locate(self, op: BusOp, address: object, value: object) -> Decoded | BusResult:
        index = _as_int(address)
        if index is None:
            return self._refuse(op, address, value, BusErrorKind.UNMAPPED)
        if index % WORD_BYTES:
            return self._refuse(op, index, value, BusErrorKind.MISALIGNED)
        found = self.decode(index)
        if found is None:
            return self._refuse(op, index, value, BusErrorKind.UNMAPPED)
        return found

    def _refuse(self, op: BusOp, address: object, value: object, kind: BusErrorKind) -> BusResult:
        self._errors[kind] += 1
        count = self._errors[kind]
        level = logging.WARNING if _is_power_of_ten(count) else logging.DEBUG
        if logger.isEnabledFor(level):
            logger.log(
                level,
                "bus error %s: %s at %s value %s (%d of this kind so far)",
                kind.value,
                op.value,
                _hex(address),
                _hex(value),
                count,
            )
        return BusResult(0, kind)


@mypyc_attr(allow_interpreted_subclasses=True)
class RecordingBus(Bus):
    """A `Bus` that records every access, in order, with its outcome."""

    def __init__(self, window_bytes: int = WINDOW_BYTES) -> None:
        super().__init__(window_bytes)
        self.accesses: list[BusAccess] = []

    def read(self, address: object) -> BusResult:
        result = super().read(address)
        self.accesses.append(BusAccess(BusOp.READ, address, result.value, result.error))
        return result

    def write(self, address: object, value: object) -> BusResult:
        result = super().write(address, value)
        self.accesses.append(BusAccess(BusOp.WRITE, address, value, result.error))
        return result

    def read_word(self, address: object) -> int | None:
        return self._read_word_via_read(address)

    def write_word(self, address: object, value: object) -> bool:
        return self._write_word_via_write(address, value)

    def writes(self) -> list[BusAccess]:
        """Recorded writes only."""
        return [a for a in self.accesses if a.op is BusOp.WRITE]

    def clear(self) -> None:
        """Forget the recorded accesses."""
        self.accesses.clear()


def _as_int(x: object) -> int | None:
    """``x`` as an int if it is an integer of any kind (int, bool, NumPy integer), else None.

    ``operator.index`` decides: a runtime protocol check would be several times slower on
    the path every bus access takes."""
    if type(x) is int:
        return x
    try:
        return operator.index(x)  # type: ignore[arg-type]
    except TypeError:
        return None


def _is_power_of_ten(n: int) -> bool:
    while n >= 10 and n % 10 == 0:
        n //= 10
    return n == 1


def _hex(value: object) -> str:
    return f"{value:#010x}" if isinstance(value, int) else repr(value)

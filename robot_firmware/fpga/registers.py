"""Register declarations as data, and the peripheral base class that gives them meaning.

A peripheral model declares each of its registers once, as a frozen `Register` with
its offset, access kind, reset value, bit fields and a one-line description, every
argument by keyword:

    CTRL = Register(
        name="CTRL",
        offset=0x00,
        access=Access.RW,
        reset=0,
        fields=(Field(name="EN", msb=0, lsb=0, doc="1 = output enabled"),),
        doc="Enable.",
    )
    CTRL_EN = CTRL.field("EN")

Each field the model or a driver touches gets a `FieldHandle` like `CTRL_EN`, declared
beside its register: it carries the register's offset and the field's mask and shift,
so using it costs no lookup, and a misspelt field name fails when the module is
imported rather than when the field is first used. This module turns the
declarations into behaviour, so a peripheral only adds its side effects:

* bits not covered by any field are reserved: they always read as zero and writes
  to them are dropped;
* RW stores what is written; WO passes the written value to the peripheral and
  stores nothing; W1C clears the bits written as 1; RO and RC (read-to-clear)
  cannot be written, WO cannot be read;
* the processor side is `read(offset)` / `write(offset, value)`; the hardware side
  is the `hw_*` methods of each peripheral; time-driven behaviour is `tick(dt_ns)`.

Access legality is checked by `Bus`, which turns an illegal access into a counted
bus error. Calling `Peripheral.read` / `write` directly with an illegal access is a
programming error and raises `RegisterAccessError`.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import ClassVar

from robot_firmware.fpga.address_map import WINDOW_BYTES

WORD_BITS = 32
WORD_BYTES = 4
WORD_MASK = 0xFFFF_FFFF


class Access(enum.Enum):
    """How the processor may access a register."""

    RW = "RW"
    RO = "RO"
    WO = "WO"
    W1C = "W1C"
    RC = "RC"

    @property
    def readable(self) -> bool:
        return self is not Access.WO

    @property
    def writable(self) -> bool:
        return self in _WRITABLE

    @property
    def clears_on_read(self) -> bool:
        return self is Access.RC

    @property
    def meaning(self) -> str:
        return _ACCESS_MEANING[self]


_WRITABLE = frozenset({Access.RW, Access.WO, Access.W1C})

_ACCESS_MEANING = {
    Access.RW: "read/write",
    Access.RO: "read-only; a write is a bus error",
    Access.WO: "write-only; a read is a bus error",
    Access.W1C: "read; writing 1 to a bit clears it, writing 0 leaves it",
    Access.RC: "read-only; a read returns the value and clears it",
}


def as_signed32(value: int) -> int:
    """Interpret a 32-bit register word as two's complement."""
    value &= WORD_MASK
    return value - (1 << WORD_BITS) if value & (1 << (WORD_BITS - 1)) else value


def as_unsigned32(value: int) -> int:
    """Encode a signed integer as a 32-bit two's complement word (wraps)."""
    return value & WORD_MASK


@dataclass(frozen=True, kw_only=True)
class Field:
    """A named bit range `[msb:lsb]` inside a register; read and written through a `FieldHandle`."""

    name: str
    msb: int
    lsb: int
    doc: str
    width: int = dataclasses.field(init=False, repr=False, compare=False)
    mask: int = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a field needs a name")
        if not 0 <= self.lsb <= self.msb < WORD_BITS:
            raise ValueError(f"field {self.name}: bit range [{self.msb}:{self.lsb}] is invalid")
        width = self.msb - self.lsb + 1
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "mask", ((1 << width) - 1) << self.lsb)

    @property
    def bits(self) -> str:
        return f"[{self.msb}]" if self.msb == self.lsb else f"[{self.msb}:{self.lsb}]"


@dataclass(frozen=True, kw_only=True)
class Register:
    """One 32-bit register: where it is, how it may be accessed, what its bits mean.

    `affects` names the other registers of the same peripheral that a write to this
    one may change (its side effects), so that tests and docs can check and show them.
    """

    name: str
    offset: int
    access: Access
    reset: int
    fields: tuple[Field, ...]
    doc: str
    affects: tuple[str, ...] = ()
    mask: int = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.offset % WORD_BYTES or not 0 <= self.offset < WINDOW_BYTES:
            raise ValueError(f"register {self.name}: offset {self.offset:#x} is not a word slot")
        if not self.fields:
            raise ValueError(f"register {self.name}: declare at least one field")
        mask = 0
        names: set[str] = set()
        for f in self.fields:
            if mask & f.mask:
                raise ValueError(f"register {self.name}: field {f.name} overlaps another field")
            if f.name in names:
                raise ValueError(f"register {self.name}: field name {f.name} is repeated")
            names.add(f.name)
            mask |= f.mask
        if self.reset & ~mask:
            raise ValueError(f"register {self.name}: reset {self.reset:#x} sets reserved bits")
        object.__setattr__(self, "mask", mask)

    def field(self, name: str) -> FieldHandle:
        """A handle on the field called `name`; a KeyError names the fields there are.

        Call it once, beside the declaration, and keep the handle.
        """
        for f in self.fields:
            if f.name == name:
                return FieldHandle(register=self, field=f)
        known = ", ".join(f.name for f in self.fields)
        raise KeyError(f"register {self.name} has no field {name} (fields: {known})")

    def with_reset(self, reset: int) -> Register:
        """The same declaration with another reset value (for per-instance constants)."""
        return replace(self, reset=reset)


@dataclass(frozen=True, kw_only=True, slots=True)
class FieldHandle:
    """One field of one register, resolved once: the register's offset, the field's mask and shift.

    Made by `Register.field`. `extract` and `insert` work on a whole register word;
    `Peripheral._get_field` and `_set_bits` work on the stored word at `offset`.
    """

    register: Register
    field: Field
    offset: int = dataclasses.field(init=False, repr=False, compare=False)
    mask: int = dataclasses.field(init=False, repr=False, compare=False)
    shift: int = dataclasses.field(init=False, repr=False, compare=False)
    width: int = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not any(f is self.field for f in self.register.fields):
            raise ValueError(f"field {self.field.name} is not a field of {self.register.name}")
        object.__setattr__(self, "offset", self.register.offset)
        object.__setattr__(self, "mask", self.field.mask)
        object.__setattr__(self, "shift", self.field.lsb)
        object.__setattr__(self, "width", self.field.width)

    @property
    def name(self) -> str:
        """`REGISTER.FIELD`."""
        return f"{self.register.name}.{self.field.name}"

    def extract(self, word: int) -> int:
        """This field's value inside the register word `word`."""
        return (word & self.mask) >> self.shift

    def insert(self, word: int, value: int) -> int:
        """`word` with this field replaced by `value` (truncated to the field width)."""
        return (word & ~self.mask & WORD_MASK) | ((value << self.shift) & self.mask)


class RegisterAccessError(ValueError):
    """A peripheral was called directly with an access its declarations forbid."""


class Peripheral:
    """Register storage and access semantics shared by every FPGA IP model.

    Subclasses pass their declarations, register write side effects in
    `self._write_actions` (offset -> callback taking the masked written value), keep
    their hardware state in attributes and mirror it into registers with `_store`
    (whole words) and `_set_bits` (field handles).
    """

    TITLE: ClassVar[str] = "Peripheral"
    SUMMARY: ClassVar[str] = ""

    def __init__(self, name: str, registers: Iterable[Register]) -> None:
        self.name = name
        self.registers: tuple[Register, ...] = tuple(registers)
        self._by_offset: dict[int, Register] = {}
        self._by_name: dict[str, Register] = {}
        for reg in self.registers:
            if reg.offset in self._by_offset:
                raise ValueError(f"{name}: two registers at offset {reg.offset:#x}")
            if reg.name in self._by_name:
                raise ValueError(f"{name}: register name {reg.name} is repeated")
            self._by_offset[reg.offset] = reg
            self._by_name[reg.name] = reg
        for reg in self.registers:
            unknown = [a for a in reg.affects if a not in self._by_name]
            if unknown:
                raise ValueError(f"{name}.{reg.name}: affects unknown registers {unknown}")
        self._values: dict[int, int] = {reg.offset: reg.reset for reg in self.registers}
        self._write_actions: dict[int, Callable[[int], None]] = {}
        self._reads: dict[int, bool] = {
            reg.offset: reg.access.clears_on_read for reg in self.registers if reg.access.readable
        }
        """Readable offsets, and whether a read clears the register (looked up once here)."""
        self._writes: dict[int, tuple[int, Callable[[dict[int, int], Register, int], None]]] = {
            reg.offset: (reg.mask, _WRITE_SEMANTICS[reg.access])
            for reg in self.registers
            if reg.access.writable
        }
        """Writable offsets: the register's mask and its write semantics."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    # -- declarations ----------------------------------------------------------------

    def register_at(self, offset: int) -> Register | None:
        """The register declared at `offset`, or None."""
        return self._by_offset.get(offset)

    def register(self, name: str) -> Register:
        """The register called `name`."""
        return self._by_name[name]

    # -- processor side --------------------------------------------------------------

    def read(self, offset: int) -> int:
        """A 32-bit processor read; RC registers clear as they are read."""
        clears = self._reads.get(offset)
        if clears is None:
            reg = self._declared(offset)
            raise RegisterAccessError(f"{self.name}.{reg.name} is {reg.access.value}")
        value = self._values[offset]
        if clears:
            self._values[offset] = 0
        return value

    def write(self, offset: int, value: int) -> None:
        """A 32-bit processor write; reserved bits of `value` are dropped."""
        plan = self._writes.get(offset)
        if plan is None:
            reg = self._declared(offset)
            raise RegisterAccessError(f"{self.name}.{reg.name} is {reg.access.value}")
        if not 0 <= value <= WORD_MASK:
            raise RegisterAccessError(f"{value:#x} does not fit 32 bits")
        mask, semantics = plan
        masked = value & mask
        semantics(self._values, self._by_offset[offset], masked)
        action = self._write_actions.get(offset)
        if action is not None:
            action(masked)

    # -- hardware side and introspection ---------------------------------------------

    def tick(self, dt_ns: int) -> None:
        """Advance the peripheral's time-driven behaviour by `dt_ns` (default: none)."""
        del dt_ns

    def quiet_slices(self, slice_ns: int) -> int | None:
        """How many whole fabric slices of `slice_ns` from now pass with nothing falling due
        in this IP (None: no limit).  Over those, one `tick` of their sum leaves the same
        state as a `tick` per slice: `Fabric.advance` merges them.  An IP whose `tick` does
        anything must say when its next event falls (`slices_before_due`)."""
        del slice_ns
        return None

    def peek(self, offset: int) -> int:
        """The stored bits of the register at `offset`, with no read side effect."""
        self._declared(offset)
        return self._values[offset]

    def hw_force(self, offset: int, value: int) -> None:
        """Overwrite a register's stored bits (fault injection, tests).

        Reserved bits are dropped; no side effect runs and the model's internal
        state is not touched, so this shows only in what the processor reads.
        """
        reg = self._declared(offset)
        self._values[offset] = value & reg.mask

    def _declared(self, offset: int) -> Register:
        reg = self._by_offset.get(offset)
        if reg is None:
            raise RegisterAccessError(f"{self.name}: no register at offset {offset:#x}")
        return reg

    def _store(self, reg: Register, value: int) -> None:
        self._values[reg.offset] = value & reg.mask

    def _get(self, reg: Register) -> int:
        return self._values[reg.offset]

    def _get_field(self, field: FieldHandle) -> int:
        return field.extract(self._values[field.offset])

    def _set_bits(self, *fields: FieldHandle) -> None:
        """Set every bit of each of `fields` (event flags, status bits)."""
        values = self._values
        for field in fields:
            values[field.offset] |= field.mask


def slices_before_due(remaining_ns: int, slice_ns: int) -> int:
    """Whole slices of `slice_ns` that pass before the one in which a countdown with
    `remaining_ns` left reaches zero (0 when it reaches zero in the next slice)."""
    return max(0, -(-remaining_ns // slice_ns) - 1)


def _write_stored(values: dict[int, int], reg: Register, masked: int) -> None:
    values[reg.offset] = masked


def _write_nothing(values: dict[int, int], reg: Register, masked: int) -> None:
    del values, reg, masked


def _write_one_to_clear(values: dict[int, int], reg: Register, masked: int) -> None:
    values[reg.offset] &= ~masked & WORD_MASK


_WRITE_SEMANTICS: dict[Access, Callable[[dict[int, int], Register, int], None]] = {
    Access.RW: _write_stored,
    Access.WO: _write_nothing,
    Access.W1C: _write_one_to_clear,
}

"""Indoor positioning receiver IP: global pose fixes from the lab's tracking system (DESIGN §4).

The world delivers fixes through `hw_set_fix` (about 20 Hz, millimetre noise) and can
cut them. Units: X_UM and Y_UM are signed micrometres in the world frame (saturating
at +/-2**31 um, about 2.1 km); HEADING_URAD is signed microradians in (-pi, pi].

A fix is new when its `stamp_ns` differs from the last accepted one, so the world may
repeat the current fix in every sense message. A new fix updates X/Y/HEADING, SEQ
increments, VALID is set, NEW_FIX is raised and AGE_MS restarts from 0. A fix marked
invalid (or `hw_cut_fix`) clears VALID and raises LOST, keeping the last position. A
fix with a non-finite number is dropped and counted in REJECTED. When no new fix has
come for STALE_MS, VALID clears by itself and LOST is raised.

To read a consistent fix a driver reads SEQ, the pose, then SEQ again, and retries if
the two differ.

A register fault (robot_firmware/fpga/faults.py) can block the fixes (`hw_block_fixes`, an
outage): nothing is latched, AGE_MS grows and VALID clears after STALE_MS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from robot_firmware.fpga.registers import (
    WORD_BITS,
    WORD_MASK,
    Access,
    Field,
    Peripheral,
    Register,
    as_unsigned32,
    slices_before_due,
)

UM_PER_M = 1_000_000
URAD_PER_RAD = 1_000_000
NS_PER_MS = 1_000_000
RESET_STALE_MS = 500
_INT32_MAX = (1 << (WORD_BITS - 1)) - 1
_INT32_MIN = -(1 << (WORD_BITS - 1))


@dataclass(frozen=True)
class PositionFix:
    """One pose fix as the tracking system sends it."""

    x_m: float
    y_m: float
    heading_rad: float
    stamp_ns: int
    valid: bool = True


X_UM = Register(
    name="X_UM",
    offset=0x00,
    access=Access.RO,
    reset=0,
    fields=(Field(name="UM", msb=31, lsb=0, doc="signed micrometres, world frame"),),
    doc="x of the last fix.",
)
Y_UM = Register(
    name="Y_UM",
    offset=0x04,
    access=Access.RO,
    reset=0,
    fields=(Field(name="UM", msb=31, lsb=0, doc="signed micrometres, world frame"),),
    doc="y of the last fix.",
)
HEADING_URAD = Register(
    name="HEADING_URAD",
    offset=0x08,
    access=Access.RO,
    reset=0,
    fields=(Field(name="URAD", msb=31, lsb=0, doc="signed microradians in (-pi, pi]"),),
    doc="Heading of the last fix.",
)
SEQ = Register(
    name="SEQ",
    offset=0x0C,
    access=Access.RO,
    reset=0,
    fields=(Field(name="SEQ", msb=31, lsb=0, doc="increments on every new fix, wraps"),),
    doc="Fix sequence counter.",
)
STATUS = Register(
    name="STATUS",
    offset=0x10,
    access=Access.RO,
    reset=0,
    fields=(Field(name="VALID", msb=0, lsb=0, doc="the last fix is usable: not cut, not stale"),),
    doc="Receiver state.",
)
STATUS_VALID = STATUS.field("VALID")
EVENTS = Register(
    name="EVENTS",
    offset=0x14,
    access=Access.RC,
    reset=0,
    fields=(
        Field(name="NEW_FIX", msb=0, lsb=0, doc="a new fix arrived"),
        Field(name="LOST", msb=1, lsb=1, doc="VALID went from 1 to 0"),
    ),
    doc="Receiver events; a read returns and clears them.",
)
EVENTS_NEW_FIX = EVENTS.field("NEW_FIX")
EVENTS_LOST = EVENTS.field("LOST")
AGE_MS = Register(
    name="AGE_MS",
    offset=0x18,
    access=Access.RO,
    reset=WORD_MASK,
    fields=(
        Field(
            name="MS",
            msb=31,
            lsb=0,
            doc="milliseconds since the last new fix; all ones before the first",
        ),
    ),
    doc="Age of the last fix.",
)
STALE_MS = Register(
    name="STALE_MS",
    offset=0x1C,
    access=Access.RW,
    reset=RESET_STALE_MS,
    fields=(Field(name="MS", msb=15, lsb=0, doc="milliseconds; 0 = never stale"),),
    doc="VALID clears when no new fix has come for this long.",
)
REJECTED = Register(
    name="REJECTED",
    offset=0x20,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNT", msb=31, lsb=0, doc="fixes dropped for non-finite values, wraps"),),
    doc="Number of malformed fixes.",
)

REGISTERS = (X_UM, Y_UM, HEADING_URAD, SEQ, STATUS, EVENTS, AGE_MS, STALE_MS, REJECTED)


def wrap_angle_rad(angle_rad: float) -> float:
    """`angle_rad` wrapped to (-pi, pi]."""
    wrapped = math.remainder(angle_rad, math.tau)
    return math.pi if wrapped <= -math.pi else wrapped


def _saturate_int32(value: float) -> int:
    """Round to the nearest int32, saturating (a finite fix in metres can overflow in µm)."""
    if math.isinf(value):
        return _INT32_MAX if value > 0 else _INT32_MIN
    return min(max(round(value), _INT32_MIN), _INT32_MAX)


class PositioningReceiver(Peripheral):
    """Latest pose fix of the indoor tracking system, with validity and age."""

    TITLE = "Indoor positioning receiver"
    SUMMARY = (
        "Pose fixes from the lab tracking system: X_UM, Y_UM in signed micrometres, "
        "HEADING_URAD in signed microradians within (-pi, pi]. SEQ increments on each new fix; "
        "VALID clears when the world cuts the fixes or none has come for STALE_MS. Read SEQ "
        "before and after the pose and retry if it changed."
    )

    def __init__(self, name: str = "positioning") -> None:
        super().__init__(name, REGISTERS)
        self._last_stamp_ns: int | None = None
        self._age_ns: int | None = None
        self._valid = False
        self._fixes_blocked = False

    def tick(self, dt_ns: int) -> None:
        if self._age_ns is None:
            return
        self._age_ns += dt_ns
        self._store(AGE_MS, min(self._age_ns // NS_PER_MS, WORD_MASK))
        stale_ms = self._get(STALE_MS)
        if self._valid and stale_ms and self._age_ns >= stale_ms * NS_PER_MS:
            self._set_valid(False)

    def quiet_slices(self, slice_ns: int) -> int | None:
        stale_ms = self._get(STALE_MS)
        if self._age_ns is None or not self._valid or not stale_ms:
            return None
        return slices_before_due(stale_ms * NS_PER_MS - self._age_ns, slice_ns)

    # -- hardware side ---------------------------------------------------------------

    def hw_set_fix(self, fix: PositionFix) -> None:
        """Deliver a fix from the tracking system (or its loss, when `fix.valid` is False)."""
        if self._fixes_blocked:
            return
        if not fix.valid:
            self._set_valid(False)
            return
        if not all(math.isfinite(v) for v in (fix.x_m, fix.y_m, fix.heading_rad)):
            self._store(REJECTED, (self._get(REJECTED) + 1) & WORD_MASK)
            return
        if fix.stamp_ns == self._last_stamp_ns:
            return
        self._last_stamp_ns = fix.stamp_ns
        self._store(X_UM, as_unsigned32(_saturate_int32(fix.x_m * UM_PER_M)))
        self._store(Y_UM, as_unsigned32(_saturate_int32(fix.y_m * UM_PER_M)))
        heading_urad = round(wrap_angle_rad(fix.heading_rad) * URAD_PER_RAD)
        self._store(HEADING_URAD, as_unsigned32(heading_urad))
        self._store(SEQ, (self._get(SEQ) + 1) & WORD_MASK)
        self._age_ns = 0
        self._store(AGE_MS, 0)
        self._set_bits(EVENTS_NEW_FIX)
        self._set_valid(True)

    def hw_cut_fix(self) -> None:
        """The tracking system stops delivering: VALID clears."""
        self._set_valid(False)

    def hw_valid(self) -> bool:
        return self._valid

    def hw_block_fixes(self, blocked: bool) -> None:
        """Fault injection: while blocked the receiver latches nothing the tracking system
        sends (an outage): AGE_MS grows, VALID clears after STALE_MS. The next new fix after
        the block is taken as usual."""
        self._fixes_blocked = blocked

    # -- internals -------------------------------------------------------------------

    def _set_valid(self, valid: bool) -> None:
        if self._valid and not valid:
            self._set_bits(EVENTS_LOST)
        self._valid = valid
        self._store(STATUS, STATUS_VALID.insert(0, int(valid)))

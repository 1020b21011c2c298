"""Quadrature encoder (QEP) IP: one instance per wheel.

The pins carry the encoder's A/B signals; the IP decodes every edge of both (4x
decoding), so one encoder line period is 4 counts. In the emulation the world gives
the running 4x edge count of the wheel (`hw_set_encoder_counts`); the IP counts the
change since the previous value. The first value after power-up only sets the
baseline: edges before power-up are not seen.

COUNT is the signed 32-bit position (two's complement); when it wraps past +/-2**31
the OVERFLOW event is set. Every WINDOW_TICKS fabric clock cycles the counts of the
window are latched into SPEED (signed counts per window) and pushed through the speed
filter into SPEED_FILTERED, and SPEED_NEW is set. If one `tick` spans several
windows, SPEED is the mean per window over them. WINDOW_TICKS 0 stops the latching.

Register faults (robot_firmware/fpga/faults.py) cut the encoder lines (`hw_cut_lines`) or
force bits of COUNT (`hw_force_count_bits`).
"""

from __future__ import annotations

import operator
from collections.abc import Callable

from robot_firmware.fpga.clock import DEFAULT_FABRIC_CLOCK_HZ
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

NS_PER_S = 1_000_000_000
RESET_WINDOW_TICKS = 500_000  # 10 ms at the 50 MHz reset fabric clock
_COUNT_MIN = -(1 << (WORD_BITS - 1))
_COUNT_SPAN = 1 << WORD_BITS

COUNT = Register(
    name="COUNT",
    offset=0x00,
    access=Access.RO,
    reset=0,
    fields=(
        Field(
            name="COUNT", msb=31, lsb=0, doc="signed two's complement, 4 counts per encoder line"
        ),
    ),
    doc="Wheel position in 4x-decoded encoder counts.",
)
SPEED = Register(
    name="SPEED",
    offset=0x04,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNTS", msb=31, lsb=0, doc="signed two's complement"),),
    doc="Counts during the last speed window.",
)
SPEED_FILTERED = Register(
    name="SPEED_FILTERED",
    offset=0x08,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNTS", msb=31, lsb=0, doc="signed two's complement"),),
    doc="SPEED after the speed filter.",
)
STATUS = Register(
    name="STATUS",
    offset=0x0C,
    access=Access.RO,
    reset=0,
    fields=(
        Field(name="DIR", msb=0, lsb=0, doc="direction of the last count change: 0 up, 1 down"),
    ),
    doc="Decoder state.",
)
STATUS_DIR = STATUS.field("DIR")
EVENTS = Register(
    name="EVENTS",
    offset=0x10,
    access=Access.W1C,
    reset=0,
    fields=(
        Field(name="OVERFLOW", msb=0, lsb=0, doc="COUNT wrapped past +/-2^31"),
        Field(name="SPEED_NEW", msb=1, lsb=1, doc="SPEED was latched"),
    ),
    doc="Sticky events; write 1 to clear.",
)
EVENTS_OVERFLOW = EVENTS.field("OVERFLOW")
EVENTS_SPEED_NEW = EVENTS.field("SPEED_NEW")
CTRL = Register(
    name="CTRL",
    offset=0x14,
    access=Access.RW,
    reset=0b01,
    fields=(
        Field(name="EN", msb=0, lsb=0, doc="1 = count edges; 0 = edges are ignored"),
        Field(name="INVERT", msb=1, lsb=1, doc="1 = count down for a forward turn"),
    ),
    doc="Counter control.",
)
CTRL_EN = CTRL.field("EN")
CTRL_INVERT = CTRL.field("INVERT")
CLEAR = Register(
    name="CLEAR",
    offset=0x18,
    access=Access.WO,
    reset=0,
    fields=(Field(name="COUNT", msb=0, lsb=0, doc="1 sets COUNT to 0"),),
    doc="Position clear.",
    affects=("COUNT",),
)
CLEAR_COUNT = CLEAR.field("COUNT")
WINDOW_TICKS = Register(
    name="WINDOW_TICKS",
    offset=0x1C,
    access=Access.RW,
    reset=RESET_WINDOW_TICKS,
    fields=(
        Field(name="TICKS", msb=31, lsb=0, doc="fabric clock cycles; 0 stops the speed latch"),
    ),
    doc="Speed window length.",
)

REGISTERS = (COUNT, SPEED, SPEED_FILTERED, STATUS, EVENTS, CTRL, CLEAR, WINDOW_TICKS)


def _identity(sample: int) -> int:
    return sample


def _fixed_clock_hz() -> int:
    return DEFAULT_FABRIC_CLOCK_HZ


class Qep(Peripheral):
    """4x quadrature decoder with position count and windowed speed."""

    TITLE = "Quadrature encoder (QEP)"
    SUMMARY = (
        "One instance per wheel. COUNT is the signed 4x-decoded position; OVERFLOW is set when "
        "it wraps. Every WINDOW_TICKS fabric cycles the counts of the window are latched into "
        "SPEED and, through speed_filter, SPEED_FILTERED. The first encoder value after "
        "power-up is the baseline."
    )

    def __init__(
        self,
        name: str,
        clock_hz: Callable[[], int] = _fixed_clock_hz,
        speed_filter: Callable[[int], int] = _identity,
    ) -> None:
        super().__init__(name, REGISTERS)
        self._clock_hz = clock_hz
        self._speed_filter = speed_filter
        self._last_edges: int | None = None
        self._count = 0
        self._window_counts = 0
        self._window_elapsed_ns = 0
        self._lines_cut = False
        self._count_forced_mask = 0
        self._count_forced_bits = 0
        self._write_actions = {CLEAR.offset: self._on_clear}

    def tick(self, dt_ns: int) -> None:
        window_ns = self._get(WINDOW_TICKS) * NS_PER_S // max(1, self._clock_hz())
        if window_ns == 0:
            self._window_elapsed_ns = 0
            self._window_counts = 0
            return
        self._window_elapsed_ns += dt_ns
        windows, self._window_elapsed_ns = divmod(self._window_elapsed_ns, window_ns)
        if windows == 0:
            return
        counts = self._window_counts
        per_window = abs(counts) // windows
        speed = per_window if counts >= 0 else -per_window
        self._window_counts = 0
        self._store(SPEED, as_unsigned32(speed))
        self._store(SPEED_FILTERED, as_unsigned32(self._speed_filter(speed)))
        self._set_bits(EVENTS_SPEED_NEW)

    def quiet_slices(self, slice_ns: int) -> int | None:
        window_ns = self._get(WINDOW_TICKS) * NS_PER_S // max(1, self._clock_hz())
        if window_ns == 0:
            return None
        return slices_before_due(window_ns - self._window_elapsed_ns, slice_ns)

    # -- hardware side ---------------------------------------------------------------

    def hw_set_encoder_counts(self, edges_counts: int) -> None:
        """The wheel encoder's running 4x edge count, as the pins have seen it so far."""
        edges = operator.index(edges_counts)
        previous, self._last_edges = self._last_edges, edges
        if previous is None or self._lines_cut or not self._get_field(CTRL_EN):
            return
        delta = edges - previous
        if self._get_field(CTRL_INVERT):
            delta = -delta
        if delta == 0:
            return
        self._window_counts += delta
        self._store(STATUS, STATUS_DIR.insert(0, int(delta < 0)))
        position = self._count + delta
        wrapped = (position - _COUNT_MIN) % _COUNT_SPAN + _COUNT_MIN
        if wrapped != position:
            self._set_bits(EVENTS_OVERFLOW)
        self._count = wrapped
        self._store_count()

    def hw_count(self) -> int:
        """The decoder's position as a signed integer (COUNT but for forced bits)."""
        return self._count

    def hw_cut_lines(self, cut: bool) -> None:
        """Fault injection: while the A/B lines are cut the decoder sees no edge, so COUNT
        holds and SPEED falls to 0; the edges of the cut are lost, counting resumes after it."""
        self._lines_cut = cut

    def hw_force_count_bits(self, mask: int, bits: int) -> None:
        """Fault injection: the bits of COUNT set in `mask` read as the same bits of `bits`,
        whatever the position (stuck register bits); mask 0 releases them. The position
        itself counts on, so a released COUNT reads true at once."""
        self._count_forced_mask = mask & WORD_MASK
        self._count_forced_bits = bits & self._count_forced_mask
        self._store_count()

    # -- side effects ----------------------------------------------------------------

    def _on_clear(self, value: int) -> None:
        if CLEAR_COUNT.extract(value):
            self._count = 0
            self._store_count()

    def _store_count(self) -> None:
        word = as_unsigned32(self._count)
        if self._count_forced_mask:
            word = (word & ~self._count_forced_mask) | self._count_forced_bits
        self._store(COUNT, word)

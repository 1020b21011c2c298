"""PLL and clock divider IP: the clock sources of the other IPs.

A 50 MHz board oscillator feeds a PLL, f_pll = f_ref * MULT / DIV, whose output is
divided into two clocks: C0, the fabric clock that times the PWM, QEP and sonar IPs
(their *_TICKS registers count C0 cycles), and C1, the burst clock of the sonar
transducers. At reset f_pll = 100 MHz, C0 = 50 MHz, C1 = 40 kHz.

Reconfiguration: the driver writes PLL_MULT, PLL_DIV, C0_DIV, C1_DIV, then APPLY.
LOCKED drops at once and rises LOCK_TIME_NS of `tick` time later; the new
frequencies take effect (and show in the *_HZ registers) when LOCKED rises. Until
then the consumers keep the old clock. A setting with a zero divider or f_pll outside
PLL_MIN_HZ..PLL_MAX_HZ is refused: CFG_ERROR is set and the running clocks stay.
Frequencies are whole hertz, rounded down.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from robot_firmware.fpga.registers import Access, Field, Peripheral, Register, slices_before_due

REF_CLOCK_HZ = 50_000_000
LOCK_TIME_NS = 20_000
PLL_MIN_HZ = 10_000_000
PLL_MAX_HZ = 400_000_000


@dataclass(frozen=True)
class ClockSetting:
    """One configuration of the PLL and the two dividers (its frequencies computed once: the
    QEP models ask for C0 at every fabric tick)."""

    mult: int
    div: int
    c0_div: int
    c1_div: int

    @property
    def valid(self) -> bool:
        if min(self.mult, self.div, self.c0_div, self.c1_div) < 1:
            return False
        return PLL_MIN_HZ <= self.pll_hz <= PLL_MAX_HZ

    @cached_property
    def pll_hz(self) -> int:
        return REF_CLOCK_HZ * self.mult // self.div if self.div else 0

    @cached_property
    def c0_hz(self) -> int:
        return self.pll_hz // self.c0_div if self.c0_div else 0

    @cached_property
    def c1_hz(self) -> int:
        return self.pll_hz // self.c1_div if self.c1_div else 0


RESET_SETTING = ClockSetting(mult=2, div=1, c0_div=2, c1_div=2500)
DEFAULT_FABRIC_CLOCK_HZ = RESET_SETTING.c0_hz

PLL_MULT = Register(
    name="PLL_MULT",
    offset=0x00,
    access=Access.RW,
    reset=RESET_SETTING.mult,
    fields=(Field(name="MULT", msb=5, lsb=0, doc="feedback multiplier, 1..63"),),
    doc="PLL multiplier, used at the next APPLY.",
)
PLL_DIV = Register(
    name="PLL_DIV",
    offset=0x04,
    access=Access.RW,
    reset=RESET_SETTING.div,
    fields=(Field(name="DIV", msb=5, lsb=0, doc="reference divider, 1..63"),),
    doc="PLL reference divider, used at the next APPLY.",
)
C0_DIV = Register(
    name="C0_DIV",
    offset=0x08,
    access=Access.RW,
    reset=RESET_SETTING.c0_div,
    fields=(Field(name="DIV", msb=15, lsb=0, doc="divider of f_pll, 1..65535"),),
    doc="Divider of the fabric clock C0, used at the next APPLY.",
)
C1_DIV = Register(
    name="C1_DIV",
    offset=0x0C,
    access=Access.RW,
    reset=RESET_SETTING.c1_div,
    fields=(Field(name="DIV", msb=15, lsb=0, doc="divider of f_pll, 1..65535"),),
    doc="Divider of the sonar burst clock C1, used at the next APPLY.",
)
CTRL = Register(
    name="CTRL",
    offset=0x10,
    access=Access.WO,
    reset=0,
    fields=(
        Field(
            name="APPLY",
            msb=0,
            lsb=0,
            doc="1 starts a reconfiguration with the four registers above",
        ),
    ),
    doc="Reconfiguration trigger.",
    affects=("STATUS",),
)
CTRL_APPLY = CTRL.field("APPLY")
STATUS = Register(
    name="STATUS",
    offset=0x14,
    access=Access.RO,
    reset=0b01,
    fields=(
        Field(name="LOCKED", msb=0, lsb=0, doc="the PLL runs at the applied setting"),
        Field(
            name="CFG_ERROR",
            msb=1,
            lsb=1,
            doc="the last APPLY was refused; cleared by a valid APPLY",
        ),
    ),
    doc="PLL lock and configuration status.",
)
STATUS_LOCKED = STATUS.field("LOCKED")
STATUS_CFG_ERROR = STATUS.field("CFG_ERROR")
REF_HZ = Register(
    name="REF_HZ",
    offset=0x18,
    access=Access.RO,
    reset=REF_CLOCK_HZ,
    fields=(Field(name="HZ", msb=31, lsb=0, doc="hertz"),),
    doc="Reference oscillator frequency.",
)
PLL_HZ = Register(
    name="PLL_HZ",
    offset=0x1C,
    access=Access.RO,
    reset=RESET_SETTING.pll_hz,
    fields=(Field(name="HZ", msb=31, lsb=0, doc="hertz"),),
    doc="PLL output frequency in use.",
)
C0_HZ = Register(
    name="C0_HZ",
    offset=0x20,
    access=Access.RO,
    reset=RESET_SETTING.c0_hz,
    fields=(Field(name="HZ", msb=31, lsb=0, doc="hertz"),),
    doc="Fabric clock C0 in use.",
)
C1_HZ = Register(
    name="C1_HZ",
    offset=0x24,
    access=Access.RO,
    reset=RESET_SETTING.c1_hz,
    fields=(Field(name="HZ", msb=31, lsb=0, doc="hertz"),),
    doc="Sonar burst clock C1 in use.",
)

REGISTERS = (PLL_MULT, PLL_DIV, C0_DIV, C1_DIV, CTRL, STATUS, REF_HZ, PLL_HZ, C0_HZ, C1_HZ)


class ClockBlock(Peripheral):
    """PLL with two output dividers and a lock flag."""

    TITLE = "PLL and clock dividers"
    SUMMARY = (
        "f_pll = 50 MHz * MULT / DIV; C0 = f_pll / C0_DIV is the fabric clock that the "
        "*_TICKS registers of PWM, QEP and sonar count; C1 = f_pll / C1_DIV drives the sonar "
        f"bursts. APPLY drops LOCKED; it rises {LOCK_TIME_NS // 1000} us later and only then "
        f"do the new frequencies take effect. f_pll must stay within {PLL_MIN_HZ // 1_000_000}"
        f"..{PLL_MAX_HZ // 1_000_000} MHz, else APPLY sets CFG_ERROR and changes nothing."
    )

    def __init__(self, name: str = "clock") -> None:
        super().__init__(name, REGISTERS)
        self._active = RESET_SETTING
        self._pending: ClockSetting | None = None
        self._lock_remaining_ns = 0
        self._write_actions = {CTRL.offset: self._on_ctrl}

    def tick(self, dt_ns: int) -> None:
        if self._pending is None:
            return
        self._lock_remaining_ns -= dt_ns
        if self._lock_remaining_ns <= 0:
            self._active, self._pending = self._pending, None
            self._publish()

    def quiet_slices(self, slice_ns: int) -> int | None:
        if self._pending is None:
            return None
        return slices_before_due(self._lock_remaining_ns, slice_ns)

    # -- hardware side ---------------------------------------------------------------

    def hw_fabric_clock_hz(self) -> int:
        """Frequency of C0, the clock the other IPs count in."""
        return self._active.c0_hz

    def hw_locked(self) -> bool:
        return self._pending is None

    # -- side effects ----------------------------------------------------------------

    def _on_ctrl(self, value: int) -> None:
        if not CTRL_APPLY.extract(value):
            return
        setting = ClockSetting(
            mult=self._get(PLL_MULT),
            div=self._get(PLL_DIV),
            c0_div=self._get(C0_DIV),
            c1_div=self._get(C1_DIV),
        )
        if not setting.valid:
            self._set_bits(STATUS_CFG_ERROR)
            return
        self._pending = setting
        self._lock_remaining_ns = LOCK_TIME_NS
        self._store(STATUS, 0)

    def _publish(self) -> None:
        self._set_bits(STATUS_LOCKED)
        self._store(PLL_HZ, self._active.pll_hz)
        self._store(C0_HZ, self._active.c0_hz)
        self._store(C1_HZ, self._active.c1_hz)

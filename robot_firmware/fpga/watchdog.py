"""Motor watchdog IP: cuts the PWM outputs when the firmware stops kicking it.

The watchdog counts down from TIMEOUT_MS while enabled. Writing KICK_MAGIC to KICK
reloads the count from TIMEOUT_MS and, if it had expired, ends the cut. When the
count reaches zero the watchdog expires: EXPIRED is set, EXPIRE_COUNT increments and
every connected output (the PWM generators, wired by the fabric) is told to force
itself off until the next good kick. A kick with any other value is ignored and
counted in BAD_KICK_COUNT. It is enabled at reset, so a firmware that never kicks
never drives the motors for longer than the reset timeout.

A new TIMEOUT_MS takes effect at the next kick. Clearing EN stops the count and ends
a cut; setting EN again reloads the count. A TIMEOUT_MS of 0 acts as 1 ms.
"""

from __future__ import annotations

from collections.abc import Callable

from robot_firmware.fpga.registers import (
    WORD_MASK,
    Access,
    Field,
    Peripheral,
    Register,
    slices_before_due,
)

KICK_MAGIC = 0x600D_D06E
RESET_TIMEOUT_MS = 100
NS_PER_MS = 1_000_000
NS_PER_US = 1_000

CTRL = Register(
    name="CTRL",
    offset=0x00,
    access=Access.RW,
    reset=0b1,
    fields=(Field(name="EN", msb=0, lsb=0, doc="1 = counting; 0 = stopped, outputs not cut"),),
    doc="Watchdog enable.",
    affects=("STATUS", "REMAINING_US"),
)
CTRL_EN = CTRL.field("EN")
TIMEOUT_MS = Register(
    name="TIMEOUT_MS",
    offset=0x04,
    access=Access.RW,
    reset=RESET_TIMEOUT_MS,
    fields=(
        Field(name="MS", msb=15, lsb=0, doc="milliseconds, 0 acts as 1; used from the next kick"),
    ),
    doc="Time without a kick before the outputs are cut.",
)
TIMEOUT_MS_MS = TIMEOUT_MS.field("MS")
KICK = Register(
    name="KICK",
    offset=0x08,
    access=Access.WO,
    reset=0,
    fields=(
        Field(
            name="KEY",
            msb=31,
            lsb=0,
            doc=f"write 0x{KICK_MAGIC:08X} to kick; other values are counted",
        ),
    ),
    doc="Kick: reload the count and end a cut.",
    affects=("STATUS", "REMAINING_US", "BAD_KICK_COUNT"),
)
STATUS = Register(
    name="STATUS",
    offset=0x0C,
    access=Access.RO,
    reset=0b10,
    fields=(
        Field(
            name="EXPIRED", msb=0, lsb=0, doc="the timeout elapsed without a kick; outputs are cut"
        ),
        Field(name="ARMED", msb=1, lsb=1, doc="enabled and counting down"),
    ),
    doc="Watchdog state.",
)
STATUS_EXPIRED = STATUS.field("EXPIRED")
STATUS_ARMED = STATUS.field("ARMED")
REMAINING_US = Register(
    name="REMAINING_US",
    offset=0x10,
    access=Access.RO,
    reset=RESET_TIMEOUT_MS * 1000,
    fields=(Field(name="US", msb=31, lsb=0, doc="microseconds, rounded up"),),
    doc="Time left before expiry.",
)
EXPIRE_COUNT = Register(
    name="EXPIRE_COUNT",
    offset=0x14,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNT", msb=31, lsb=0, doc="expiries since reset, wraps"),),
    doc="Number of expiries.",
)
BAD_KICK_COUNT = Register(
    name="BAD_KICK_COUNT",
    offset=0x18,
    access=Access.RO,
    reset=0,
    fields=(Field(name="COUNT", msb=31, lsb=0, doc="kicks with a wrong key since reset, wraps"),),
    doc="Number of refused kicks.",
)

REGISTERS = (CTRL, TIMEOUT_MS, KICK, STATUS, REMAINING_US, EXPIRE_COUNT, BAD_KICK_COUNT)


class Watchdog(Peripheral):
    """Countdown that cuts the connected outputs when it reaches zero."""

    TITLE = "Motor watchdog"
    SUMMARY = (
        f"Counts down from TIMEOUT_MS; writing 0x{KICK_MAGIC:08X} to KICK reloads it. At zero "
        "EXPIRED is set and every PWM output is forced off until the next good kick. "
        "Enabled at reset. A new TIMEOUT_MS is used from the next kick."
    )

    def __init__(self, name: str = "watchdog") -> None:
        super().__init__(name, REGISTERS)
        self._remaining_ns = RESET_TIMEOUT_MS * NS_PER_MS
        self._expired = False
        self._enabled = True
        self._cut_listeners: list[Callable[[bool], None]] = []
        self._write_actions = {CTRL.offset: self._on_ctrl, KICK.offset: self._on_kick}

    def tick(self, dt_ns: int) -> None:
        if not self._enabled or self._expired:
            return
        self._remaining_ns = max(0, self._remaining_ns - dt_ns)
        if self._remaining_ns == 0:
            self._expire()
        self._publish()

    def quiet_slices(self, slice_ns: int) -> int | None:
        if not self._enabled or self._expired:
            return None
        return slices_before_due(self._remaining_ns, slice_ns)

    # -- hardware side ---------------------------------------------------------------

    def hw_connect_cut(self, listener: Callable[[bool], None]) -> None:
        """Call `listener(cut)` whenever the cut starts (True) or ends (False)."""
        self._cut_listeners.append(listener)
        listener(self._expired)

    def hw_expired(self) -> bool:
        return self._expired

    def hw_force_expire(self) -> None:
        """Fault injection: the count reaches zero now, as if the firmware had stopped kicking.

        EXPIRED is set, EXPIRE_COUNT increments and the outputs are cut until the next good
        kick, exactly as at a timeout (nothing new if the watchdog has already expired)."""
        self._remaining_ns = 0
        if not self._expired:
            self._expire()
        self._publish()

    # -- side effects ----------------------------------------------------------------

    def _timeout_ns(self) -> int:
        return max(1, self._get(TIMEOUT_MS)) * NS_PER_MS

    def _on_ctrl(self, value: int) -> None:
        enabled = bool(CTRL_EN.extract(value))
        if enabled and not self._enabled:
            self._remaining_ns = self._timeout_ns()
        if not enabled:
            self._set_cut(False)
        self._enabled = enabled
        self._publish()

    def _on_kick(self, value: int) -> None:
        if value != KICK_MAGIC:
            self._store(BAD_KICK_COUNT, (self._get(BAD_KICK_COUNT) + 1) & WORD_MASK)
            return
        self._remaining_ns = self._timeout_ns()
        self._set_cut(False)
        self._publish()

    def _expire(self) -> None:
        self._store(EXPIRE_COUNT, (self._get(EXPIRE_COUNT) + 1) & WORD_MASK)
        self._set_cut(True)

    def _set_cut(self, cut: bool) -> None:
        if cut == self._expired:
            return
        self._expired = cut
        for listener in self._cut_listeners:
            listener(cut)

    def _publish(self) -> None:
        status = STATUS_EXPIRED.insert(0, int(self._expired))
        status = STATUS_ARMED.insert(status, int(self._enabled and not self._expired))
        self._store(STATUS, status)
        self._store(REMAINING_US, -(-self._remaining_ns // NS_PER_US))

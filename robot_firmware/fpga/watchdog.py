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

from robot_firmware.fpga.registers import WORD_MASK, Access, Field, Peripheral, Register

KICK_MAGIC = 0x600D_D06E
RESET_TIMEOUT_MS = 100
NS_PER_MS = 1_000_000
NS_PER_US = 1_000

CTRL = Register(
    "CTRL",
    0x00,
    Access.RW,
    0b1,
    (Field("EN", 0, 0, "1 = counting; 0 = stopped, outputs not cut"),),
    "Watchdog enable.",
    affects=("STATUS", "REMAINING_US"),
)
TIMEOUT_MS = Register(
    "TIMEOUT_MS",
    0x04,
    Access.RW,
    RESET_TIMEOUT_MS,
    (Field("MS", 15, 0, "milliseconds, 0 acts as 1; used from the next kick"),),
    "Time without a kick before the outputs are cut.",
)
KICK = Register(
    "KICK",
    0x08,
    Access.WO,
    0,
    (Field("KEY", 31, 0, f"write 0x{KICK_MAGIC:08X} to kick; other values are counted"),),
    "Kick: reload the count and end a cut.",
    affects=("STATUS", "REMAINING_US", "BAD_KICK_COUNT"),
)
STATUS = Register(
    "STATUS",
    0x0C,
    Access.RO,
    0b10,
    (
        Field("EXPIRED", 0, 0, "the timeout elapsed without a kick; outputs are cut"),
        Field("ARMED", 1, 1, "enabled and counting down"),
    ),
    "Watchdog state.",
)
REMAINING_US = Register(
    "REMAINING_US",
    0x10,
    Access.RO,
    RESET_TIMEOUT_MS * 1000,
    (Field("US", 31, 0, "microseconds, rounded up"),),
    "Time left before expiry.",
)
EXPIRE_COUNT = Register(
    "EXPIRE_COUNT",
    0x14,
    Access.RO,
    0,
    (Field("COUNT", 31, 0, "expiries since reset, wraps"),),
    "Number of expiries.",
)
BAD_KICK_COUNT = Register(
    "BAD_KICK_COUNT",
    0x18,
    Access.RO,
    0,
    (Field("COUNT", 31, 0, "kicks with a wrong key since reset, wraps"),),
    "Number of refused kicks.",
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
            self._store(EXPIRE_COUNT, (self._get(EXPIRE_COUNT) + 1) & WORD_MASK)
            self._set_cut(True)
        self._publish()

    # -- hardware side ---------------------------------------------------------------

    def hw_connect_cut(self, listener: Callable[[bool], None]) -> None:
        """Call `listener(cut)` whenever the cut starts (True) or ends (False)."""
        self._cut_listeners.append(listener)
        listener(self._expired)

    def hw_expired(self) -> bool:
        return self._expired

    # -- side effects ----------------------------------------------------------------

    def _timeout_ns(self) -> int:
        return max(1, self._get(TIMEOUT_MS)) * NS_PER_MS

    def _on_ctrl(self, value: int) -> None:
        enabled = bool(CTRL.field("EN").extract(value))
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

    def _set_cut(self, cut: bool) -> None:
        if cut == self._expired:
            return
        self._expired = cut
        for listener in self._cut_listeners:
            listener(cut)

    def _publish(self) -> None:
        status = STATUS.field("EXPIRED").insert(0, int(self._expired))
        status = STATUS.field("ARMED").insert(status, int(self._enabled and not self._expired))
        self._store(STATUS, status)
        self._store(REMAINING_US, -(-self._remaining_ns // NS_PER_US))

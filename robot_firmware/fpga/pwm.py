"""Motor PWM IP: one instance per wheel, sign-magnitude drive of an H-bridge.

The output is high for DUTY_TICKS of every PERIOD_TICKS fabric clock cycles; DIR
selects the H-bridge polarity. A duty above the period saturates at 100 % (STATUS
SATURATED); a period of 0 holds the output low. While the watchdog cuts the outputs
(`hw_set_safe_stop(True)`, wired by the fabric) the output is held low whatever the
registers say; the registers keep their values, so the output resumes when the cut
ends. The world reads the resulting signed duty cycle with `hw_output`.

A register fault (robot_firmware/fpga/faults.py) can hold the output stage at a fixed duty
(`hw_hold_output`): the pins then carry it whatever the registers say, STATUS shows it, and
only the watchdog's cut still holds them low.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from robot_firmware.fpga.clock import DEFAULT_FABRIC_CLOCK_HZ
from robot_firmware.fpga.registers import Access, Field, Peripheral, Register

RESET_PERIOD_TICKS = 2_500  # 20 kHz at the 50 MHz reset fabric clock

CTRL = Register(
    name="CTRL",
    offset=0x00,
    access=Access.RW,
    reset=0,
    fields=(
        Field(name="EN", msb=0, lsb=0, doc="1 = output enabled"),
        Field(name="DIR", msb=1, lsb=1, doc="1 = reverse polarity (negative duty)"),
    ),
    doc="Enable and direction.",
    affects=("STATUS",),
)
CTRL_EN = CTRL.field("EN")
CTRL_DIR = CTRL.field("DIR")
PERIOD_TICKS = Register(
    name="PERIOD_TICKS",
    offset=0x04,
    access=Access.RW,
    reset=RESET_PERIOD_TICKS,
    fields=(Field(name="TICKS", msb=23, lsb=0, doc="fabric clock cycles; 0 holds the output low"),),
    doc="PWM period.",
    affects=("STATUS",),
)
PERIOD_TICKS_TICKS = PERIOD_TICKS.field("TICKS")
DUTY_TICKS = Register(
    name="DUTY_TICKS",
    offset=0x08,
    access=Access.RW,
    reset=0,
    fields=(
        Field(
            name="TICKS",
            msb=23,
            lsb=0,
            doc="fabric clock cycles high per period; saturates at the period",
        ),
    ),
    doc="High time per period.",
    affects=("STATUS",),
)
STATUS = Register(
    name="STATUS",
    offset=0x0C,
    access=Access.RO,
    reset=0,
    fields=(
        Field(name="SAFE_STOP", msb=0, lsb=0, doc="the watchdog holds the output low"),
        Field(name="SATURATED", msb=1, lsb=1, doc="DUTY_TICKS >= PERIOD_TICKS > 0"),
        Field(
            name="ACTIVE", msb=2, lsb=2, doc="the output is driving (enabled, not cut, duty > 0)"
        ),
    ),
    doc="Output state.",
)
STATUS_SAFE_STOP = STATUS.field("SAFE_STOP")
STATUS_SATURATED = STATUS.field("SATURATED")
STATUS_ACTIVE = STATUS.field("ACTIVE")

REGISTERS = (CTRL, PERIOD_TICKS, DUTY_TICKS, STATUS)


@dataclass(frozen=True)
class PwmOutput:
    """What the pins of one PWM generator carry."""

    duty: float
    """Signed duty cycle, -1..1 (sign = DIR); 0 when disabled or cut."""
    enabled: bool
    """Enabled, not cut by the watchdog, and with a non-zero period."""
    frequency_hz: float
    """Switching frequency; 0 when the period is 0."""


def _fixed_clock_hz() -> int:
    return DEFAULT_FABRIC_CLOCK_HZ


class Pwm(Peripheral):
    """Single-channel PWM generator with direction bit and safe-stop input."""

    TITLE = "Motor PWM"
    SUMMARY = (
        "One instance per wheel. Output high for DUTY_TICKS of every PERIOD_TICKS fabric "
        "cycles, polarity DIR. Held low while the watchdog has expired (SAFE_STOP); the "
        "registers keep their values and the output resumes after a good kick."
    )

    def __init__(self, name: str, clock_hz: Callable[[], int] = _fixed_clock_hz) -> None:
        super().__init__(name, REGISTERS)
        self._clock_hz = clock_hz
        self._safe_stop = False
        self._held_duty: float | None = None
        refresh = self._on_setting
        self._write_actions = {
            CTRL.offset: refresh,
            PERIOD_TICKS.offset: refresh,
            DUTY_TICKS.offset: refresh,
        }

    # -- hardware side ---------------------------------------------------------------

    def hw_set_safe_stop(self, active: bool) -> None:
        """Watchdog cut input: True holds the output low."""
        self._safe_stop = active
        self._on_setting(0)

    def hw_hold_output(self, duty: float | None) -> None:
        """Fault injection: the output stage holds signed `duty` (-1..1) whatever CTRL, PERIOD
        and DUTY say (a stuck generator); None releases it. The watchdog's cut still wins."""
        if duty is not None and not -1.0 <= duty <= 1.0:
            raise ValueError(f"held duty {duty} outside -1..1")
        self._held_duty = None if duty is None else float(duty)
        self._on_setting(0)

    def hw_output(self) -> PwmOutput:
        period = self._get(PERIOD_TICKS)
        if self._held_duty is not None:
            frequency_hz = self._clock_hz() / period if period else 0.0
            if self._safe_stop:
                return PwmOutput(0.0, False, frequency_hz)
            return PwmOutput(self._held_duty, True, frequency_hz)
        enabled = bool(self._get_field(CTRL_EN)) and not self._safe_stop and period > 0
        if not enabled:
            return PwmOutput(0.0, False, self._clock_hz() / period if period else 0.0)
        magnitude = min(self._get(DUTY_TICKS), period) / period
        sign = -1.0 if self._get_field(CTRL_DIR) else 1.0
        return PwmOutput(sign * magnitude, True, self._clock_hz() / period)

    # -- side effects ----------------------------------------------------------------

    def _on_setting(self, value: int) -> None:
        del value
        period = self._get(PERIOD_TICKS)
        duty = self._get(DUTY_TICKS)
        enabled = bool(self._get_field(CTRL_EN))
        held = self._held_duty
        if held is None:
            saturated = 0 < period <= duty
            active = enabled and not self._safe_stop and period > 0 and duty > 0
        else:
            saturated = abs(held) >= 1.0
            active = not self._safe_stop and held != 0.0
        status = STATUS_SAFE_STOP.insert(0, int(self._safe_stop))
        status = STATUS_SATURATED.insert(status, int(saturated))
        status = STATUS_ACTIVE.insert(status, int(active))
        self._store(STATUS, status)

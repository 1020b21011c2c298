"""Motor driver: signed wheel duty cycles to the PWM generators (5C level 5, configuration).

Each wheel has one PWM instance (`pwm0`..`pwm3`) driving an H-bridge in sign-magnitude
form: CTRL.DIR selects the polarity, DUTY_TICKS / PERIOD_TICKS the magnitude. For a
duty d in [-1, 1] the driver writes

    CTRL = EN | (DIR if d < 0)        DUTY_TICKS = round(|d| * PERIOD_TICKS)

`configure` sets PERIOD_TICKS = round(f_C0 / f_pwm) from the fabric clock C0 read in
the clock block. The driver keeps a shadow of every CTRL and DUTY_TICKS word it wrote
and writes only the words that change, so a steady command costs no bus traffic. When
a wheel changes direction, the write that lowers the drive goes first (DUTY_TICKS when
the magnitude falls, CTRL when it rises), so the output never passes through the old
magnitude in the new polarity or the new magnitude in the old one.

`disable` writes duty 0 and clears CTRL.EN on every wheel (the firmware's safe stop).

A refused write is counted in `bus_errors` and forgets the shadow of that register, so
the next `set_duty` writes it again. Non-finite duties are taken as 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import pwm as pwm_map
from robot_firmware.fpga.address_map import CLOCK_BASE, N_WHEELS, PWM_BASES
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.clock import C0_HZ, DEFAULT_FABRIC_CLOCK_HZ

DEFAULT_PWM_FREQUENCY_HZ = 20_000.0

_CTRL_FORWARD = pwm_map.CTRL_EN.insert(0, 1)
_CTRL_REVERSE = pwm_map.CTRL_DIR.insert(_CTRL_FORWARD, 1)
_MAX_PERIOD_TICKS = pwm_map.PERIOD_TICKS_TICKS.mask


class MotorDriver:
    """Signed duty per wheel, written to the PWM generators with as few bus writes as possible."""

    def __init__(self, bus: Bus, wheel_count: int = N_WHEELS) -> None:
        if not 1 <= wheel_count <= N_WHEELS:
            raise ValueError(f"wheel_count {wheel_count} outside 1..{N_WHEELS}")
        self._port = RegisterPort(bus)
        self.wheel_count = wheel_count
        bases = PWM_BASES[:wheel_count]
        self._ctrl_addresses = tuple(base + pwm_map.CTRL.offset for base in bases)
        self._period_addresses = tuple(base + pwm_map.PERIOD_TICKS.offset for base in bases)
        self._duty_addresses = tuple(base + pwm_map.DUTY_TICKS.offset for base in bases)
        self._period_ticks = [pwm_map.RESET_PERIOD_TICKS] * wheel_count
        self._ctrl_written: list[int | None] = [None] * wheel_count
        self._duty_written: list[int | None] = [None] * wheel_count
        self.last_duty: tuple[float, ...] = (0.0,) * wheel_count
        """The clipped duty per wheel of the last `set_duty` (or `stop`)."""

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    @property
    def period_ticks(self) -> tuple[int, ...]:
        """PWM period per wheel in fabric clock cycles, as last configured (reset value before)."""
        return tuple(self._period_ticks)

    def configure(self, pwm_frequency_hz: float = DEFAULT_PWM_FREQUENCY_HZ) -> None:
        """Set every PWM to `pwm_frequency_hz` with duty 0, enabled and forward.

        The period is round(f_C0 / pwm_frequency_hz) cycles of the fabric clock C0 read
        from the clock block (the reset clock when that read is refused), limited to the
        24-bit PERIOD_TICKS field.
        """
        if not (math.isfinite(pwm_frequency_hz) and pwm_frequency_hz > 0.0):
            raise ValueError(f"PWM frequency must be positive: {pwm_frequency_hz}")
        clock_hz = self._port.read(CLOCK_BASE + C0_HZ.offset)
        if clock_hz is None:
            clock_hz = DEFAULT_FABRIC_CLOCK_HZ
        period_ticks = min(max(round(clock_hz / pwm_frequency_hz), 1), _MAX_PERIOD_TICKS)
        self._ctrl_written = [None] * self.wheel_count
        self._duty_written = [None] * self.wheel_count
        for wheel in range(self.wheel_count):
            self._write_duty(wheel, 0)
            if self._port.write(self._period_addresses[wheel], period_ticks):
                self._period_ticks[wheel] = period_ticks
            self._write_ctrl(wheel, _CTRL_FORWARD)
        self.last_duty = (0.0,) * self.wheel_count

    def set_duty(self, duty: Sequence[float] | NDArray[np.float64]) -> None:
        """Command a signed duty in [-1, 1] per wheel (clipped; a non-finite duty counts as 0).

        Writes only the CTRL and DUTY_TICKS words that differ from what was last
        written. A sequence of the wrong length is a programming error (ValueError).
        """
        command = np.asarray(duty, dtype=np.float64)
        if command.shape != (self.wheel_count,):
            raise ValueError(f"{command.shape} duties for {self.wheel_count} wheels")
        clipped = [min(max(d, -1.0), 1.0) if math.isfinite(d) else 0.0 for d in command.tolist()]
        for wheel, wheel_duty in enumerate(clipped):
            duty_ticks = round(abs(wheel_duty) * self._period_ticks[wheel])
            ctrl = _CTRL_REVERSE if wheel_duty < 0.0 else _CTRL_FORWARD
            previous_ticks = self._duty_written[wheel]
            if previous_ticks is not None and duty_ticks > previous_ticks:
                self._write_ctrl(wheel, ctrl)
                self._write_duty(wheel, duty_ticks)
            else:
                self._write_duty(wheel, duty_ticks)
                self._write_ctrl(wheel, ctrl)
        self.last_duty = tuple(clipped)

    def stop(self) -> None:
        """Duty 0 on every wheel (outputs stay enabled, at zero drive)."""
        self.set_duty([0.0] * self.wheel_count)

    def disable(self) -> None:
        """Duty 0 and CTRL.EN cleared on every wheel: the outputs are off until the next
        `set_duty`, which enables them again."""
        for wheel in range(self.wheel_count):
            self._write_duty(wheel, 0)
            self._write_ctrl(wheel, 0)
        self.last_duty = (0.0,) * self.wheel_count

    # -- internals -------------------------------------------------------------------

    def _write_ctrl(self, wheel: int, ctrl: int) -> None:
        if self._ctrl_written[wheel] == ctrl:
            return
        ok = self._port.write(self._ctrl_addresses[wheel], ctrl)
        self._ctrl_written[wheel] = ctrl if ok else None

    def _write_duty(self, wheel: int, duty_ticks: int) -> None:
        if self._duty_written[wheel] == duty_ticks:
            return
        ok = self._port.write(self._duty_addresses[wheel], duty_ticks)
        self._duty_written[wheel] = duty_ticks if ok else None

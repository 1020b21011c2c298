"""PWM: signed duty from period, duty and direction; saturation; safe stop."""

from __future__ import annotations

import pytest

from robot_firmware.fpga import pwm as regs
from robot_firmware.fpga.pwm import Pwm

CTRL = regs.CTRL.offset
PERIOD = regs.PERIOD_TICKS.offset
DUTY = regs.DUTY_TICKS.offset
STATUS = regs.STATUS.offset


def test_duty_cycle_is_duty_over_period_with_the_direction_as_sign() -> None:
    pwm = Pwm("pwm0")
    pwm.write(PERIOD, 2000)
    pwm.write(DUTY, 500)
    assert pwm.hw_output().duty == 0.0
    pwm.write(CTRL, 0b01)
    assert pwm.hw_output().duty == 0.25
    assert pwm.hw_output().frequency_hz == pytest.approx(25_000.0)
    pwm.write(CTRL, 0b11)
    assert pwm.hw_output().duty == -0.25
    assert pwm.read(STATUS) == 0b100


def test_duty_above_the_period_saturates() -> None:
    pwm = Pwm("pwm0")
    pwm.write(CTRL, 0b01)
    pwm.write(DUTY, 9999)
    assert pwm.hw_output().duty == 1.0
    assert pwm.read(STATUS) == 0b110


def test_zero_period_holds_the_output_low() -> None:
    pwm = Pwm("pwm0")
    pwm.write(CTRL, 0b01)
    pwm.write(DUTY, 10)
    pwm.write(PERIOD, 0)
    output = pwm.hw_output()
    assert (output.duty, output.enabled, output.frequency_hz) == (0.0, False, 0.0)
    assert pwm.read(STATUS) == 0


def test_safe_stop_holds_the_output_low_and_keeps_the_registers() -> None:
    pwm = Pwm("pwm0")
    pwm.write(CTRL, 0b01)
    pwm.write(DUTY, 1250)
    pwm.hw_set_safe_stop(True)
    assert pwm.hw_output().duty == 0.0
    assert pwm.read(STATUS) == 0b001
    assert pwm.read(DUTY) == 1250
    pwm.hw_set_safe_stop(False)
    assert pwm.hw_output().duty == 0.5

"""Motor driver: wheel duties become the expected PWM register writes; only changes are written."""

from __future__ import annotations

import math

import pytest

from robot_firmware.drivers.motors import MotorDriver
from robot_firmware.drivers.system import SystemProbe
from robot_firmware.fpga import BusOp, Fabric, RecordingBus

EN, DIR = 0b01, 0b10
PERIOD_TICKS = 2_500  # 20 kHz at the 50 MHz reset fabric clock


def recording_fabric() -> tuple[Fabric, RecordingBus]:
    bus = RecordingBus()
    return Fabric(bus=bus), bus


def writes(bus: RecordingBus) -> list[tuple[int, int]]:
    return [(access.address, access.value) for access in bus.writes()]


def address(bus: RecordingBus, instance: str, register: str) -> int:
    return bus.address_of(instance, register)


def test_configure_sets_period_from_the_fabric_clock_with_duty_zero_and_enabled() -> None:
    fabric, bus = recording_fabric()
    motors = MotorDriver(bus)
    motors.configure(20_000.0)
    assert motors.period_ticks == (PERIOD_TICKS,) * 4
    reads = [a.address for a in bus.accesses if a.op is BusOp.READ]
    assert reads == [address(bus, "clock", "C0_HZ")]
    for i in range(4):
        assert bus.peek(address(bus, f"pwm{i}", "PERIOD_TICKS")) == PERIOD_TICKS
        assert bus.peek(address(bus, f"pwm{i}", "DUTY_TICKS")) == 0
        assert bus.peek(address(bus, f"pwm{i}", "CTRL")) == EN
    actuation = fabric.hw_read_actuation()
    assert actuation.enabled == (True,) * 4
    assert actuation.duty == (0.0,) * 4
    assert motors.last_duty == (0.0,) * 4
    assert motors.bus_errors == 0


def test_wheel_command_produces_exactly_the_expected_register_writes() -> None:
    fabric, bus = recording_fabric()
    motors = MotorDriver(bus)
    motors.configure()
    bus.clear()
    motors.set_duty([0.5, -0.25, 0.0, 1.0])
    assert writes(bus) == [
        (address(bus, "pwm0", "DUTY_TICKS"), 1_250),
        (address(bus, "pwm1", "CTRL"), EN | DIR),
        (address(bus, "pwm1", "DUTY_TICKS"), 625),
        (address(bus, "pwm3", "DUTY_TICKS"), 2_500),
    ]
    assert all(a.op is BusOp.WRITE for a in bus.accesses)
    assert fabric.hw_read_actuation().duty == pytest.approx(
        (0.5, -0.25, 0.0, 1.0), abs=1.0 / PERIOD_TICKS
    )
    assert motors.last_duty == (0.5, -0.25, 0.0, 1.0)


def test_repeated_identical_command_writes_nothing() -> None:
    _, bus = recording_fabric()
    motors = MotorDriver(bus)
    motors.configure()
    motors.set_duty([0.3, -0.7, 0.1, 0.0])
    bus.clear()
    motors.set_duty([0.3, -0.7, 0.1, 0.0])
    assert bus.accesses == []


def test_signed_duties_reach_the_pins_within_one_tick_of_quantisation() -> None:
    fabric, _ = recording_fabric()
    motors = MotorDriver(fabric.bus)
    motors.configure()
    for command in ([0.123, -0.999, 0.5004, -0.0001], [-1.0, 1.0, -0.33, 0.77]):
        motors.set_duty(command)
        assert fabric.hw_read_actuation().duty == pytest.approx(command, abs=1.0 / PERIOD_TICKS)


def test_duty_is_clipped_to_plus_minus_one_and_non_finite_is_zero() -> None:
    fabric, _ = recording_fabric()
    motors = MotorDriver(fabric.bus)
    motors.configure()
    motors.set_duty([1.7, -3.0, math.nan, 0.25])
    assert motors.last_duty == (1.0, -1.0, 0.0, 0.25)
    assert fabric.hw_read_actuation().duty == (1.0, -1.0, 0.0, 0.25)
    assert fabric.bus.peek(fabric.bus.address_of("pwm0", "DUTY_TICKS")) == PERIOD_TICKS
    motors.set_duty([math.inf, -math.inf, 0.5, 0.25])
    assert fabric.hw_read_actuation().duty == (0.0, 0.0, 0.5, 0.25)


@pytest.mark.parametrize(
    ("before", "after", "order"),
    [
        (0.8, -0.1, ("DUTY_TICKS", "CTRL")),
        (0.1, -0.8, ("CTRL", "DUTY_TICKS")),
        (-0.6, 0.2, ("DUTY_TICKS", "CTRL")),
    ],
)
def test_reversal_writes_the_register_that_lowers_the_drive_first(
    before: float, after: float, order: tuple[str, str]
) -> None:
    _, bus = recording_fabric()
    motors = MotorDriver(bus)
    motors.configure()
    motors.set_duty([before, 0.0, 0.0, 0.0])
    bus.clear()
    motors.set_duty([after, 0.0, 0.0, 0.0])
    assert [a.address for a in bus.writes()] == [address(bus, "pwm0", r) for r in order]


def test_stop_zeroes_every_duty() -> None:
    fabric, _ = recording_fabric()
    motors = MotorDriver(fabric.bus)
    motors.configure()
    motors.set_duty([0.5, -0.5, 0.5, -0.5])
    motors.stop()
    assert fabric.hw_read_actuation().duty == (0.0,) * 4
    assert motors.last_duty == (0.0,) * 4


def test_period_follows_a_reconfigured_fabric_clock() -> None:
    fabric, bus = recording_fabric()
    bus.write(address(bus, "clock", "C0_DIV"), 4)  # 100 MHz / 4 = 25 MHz
    bus.write(address(bus, "clock", "CTRL"), 1)
    assert SystemProbe(bus).wait_for_pll_lock(fabric.tick, timeout_ns=100_000)
    motors = MotorDriver(bus)
    motors.configure(10_000.0)
    assert motors.period_ticks == (2_500,) * 4
    motors.set_duty([0.5, 0.0, 0.0, 0.0])
    assert bus.peek(address(bus, "pwm0", "DUTY_TICKS")) == 1_250
    assert fabric.pwm[0].hw_output().frequency_hz == pytest.approx(10_000.0)


def test_command_of_the_wrong_length_is_refused() -> None:
    motors = MotorDriver(Fabric().bus)
    with pytest.raises(ValueError, match="4 wheels"):
        motors.set_duty([0.1, 0.2, 0.3])

"""Watchdog driver: without kicks the PWM outputs are cut; kicks in time keep them driving."""

from __future__ import annotations

from robot_firmware.drivers.motors import MotorDriver
from robot_firmware.drivers.watchdog import WatchdogDriver
from robot_firmware.fpga import Fabric

MS = 1_000_000
COMMAND = [0.5, -0.5, 0.25, -0.25]


def driving_fabric(timeout_ms: int) -> tuple[Fabric, WatchdogDriver]:
    fabric = Fabric()
    watchdog = WatchdogDriver(fabric.bus)
    watchdog.configure(timeout_ms)
    motors = MotorDriver(fabric.bus)
    motors.configure()
    motors.set_duty(COMMAND)
    return fabric, watchdog


def test_watchdog_stops_motors_without_kick() -> None:
    fabric, watchdog = driving_fabric(timeout_ms=50)
    fabric.tick(49 * MS)
    assert not watchdog.expired()
    assert fabric.hw_read_actuation().any_enabled
    fabric.tick(2 * MS)
    assert watchdog.expired()
    actuation = fabric.hw_read_actuation()
    assert actuation.watchdog_expired
    assert actuation.duty == (0.0,) * 4
    assert not actuation.any_enabled
    assert watchdog.bus_errors == 0


def test_kick_before_the_timeout_keeps_the_motors_driving() -> None:
    fabric, watchdog = driving_fabric(timeout_ms=50)
    for _ in range(10):
        fabric.tick(40 * MS)
        watchdog.kick()
    assert not watchdog.expired()
    assert fabric.hw_read_actuation().duty == (0.5, -0.5, 0.25, -0.25)


def test_kick_after_expiry_resumes_the_last_command() -> None:
    fabric, watchdog = driving_fabric(timeout_ms=20)
    fabric.tick(30 * MS)
    assert watchdog.expired()
    watchdog.kick()
    assert not watchdog.expired()
    assert fabric.hw_read_actuation().duty == (0.5, -0.5, 0.25, -0.25)


def test_configured_timeout_replaces_the_reset_timeout_at_once() -> None:
    fabric, watchdog = driving_fabric(timeout_ms=500)
    fabric.tick(200 * MS)  # past the 100 ms reset timeout
    assert not watchdog.expired()
    fabric.tick(301 * MS)
    assert watchdog.expired()

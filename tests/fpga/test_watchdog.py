"""Watchdog: the motors stop when the firmware stops kicking, and only then."""

from __future__ import annotations

from robot_firmware.fpga import Fabric
from robot_firmware.fpga.watchdog import KICK_MAGIC
from tests.fpga.register_sites import read_ok, write_ok

MS = 1_000_000


def driving_fabric(timeout_ms: int) -> Fabric:
    """A fabric with a new watchdog timeout, just kicked, and all four wheels driven."""
    fabric = Fabric()
    write_ok(fabric, "watchdog", "TIMEOUT_MS", timeout_ms)
    write_ok(fabric, "watchdog", "KICK", KICK_MAGIC)
    for i in range(4):
        write_ok(fabric, f"pwm{i}", "DUTY_TICKS", 1000)
        write_ok(fabric, f"pwm{i}", "CTRL", 0b01 if i % 2 else 0b11)
    return fabric


def test_watchdog_stops_motors_once_the_timeout_elapses_without_kick() -> None:
    fabric = driving_fabric(timeout_ms=50)
    for _ in range(49):
        fabric.tick(1 * MS)
    actuation = fabric.hw_read_actuation()
    assert actuation.duty == (-0.4, 0.4, -0.4, 0.4)
    assert actuation.enabled == (True, True, True, True)
    assert not actuation.watchdog_expired

    fabric.tick(1 * MS)
    actuation = fabric.hw_read_actuation()
    assert actuation.duty == (0.0, 0.0, 0.0, 0.0)
    assert not actuation.any_enabled
    assert actuation.watchdog_expired
    assert read_ok(fabric, "watchdog", "STATUS") == 0b01
    assert read_ok(fabric, "watchdog", "EXPIRE_COUNT") == 1
    assert read_ok(fabric, "pwm0", "STATUS") & 0b1 == 1


def test_watchdog_does_not_expire_while_kicked() -> None:
    fabric = driving_fabric(timeout_ms=20)
    for _ in range(200):
        fabric.tick(10 * MS)
        write_ok(fabric, "watchdog", "KICK", KICK_MAGIC)
    assert not fabric.hw_read_actuation().watchdog_expired
    assert read_ok(fabric, "watchdog", "EXPIRE_COUNT") == 0


def test_kick_rearms_an_expired_watchdog_and_restores_the_outputs() -> None:
    fabric = driving_fabric(timeout_ms=30)
    fabric.tick(30 * MS)
    assert fabric.hw_read_actuation().watchdog_expired
    write_ok(fabric, "watchdog", "KICK", KICK_MAGIC)
    actuation = fabric.hw_read_actuation()
    assert not actuation.watchdog_expired
    assert actuation.duty == (-0.4, 0.4, -0.4, 0.4)
    assert read_ok(fabric, "watchdog", "REMAINING_US") == 30_000
    fabric.tick(29 * MS)
    assert not fabric.hw_read_actuation().watchdog_expired
    fabric.tick(1 * MS)
    assert fabric.hw_read_actuation().watchdog_expired


def test_kick_with_a_wrong_key_is_counted_and_does_not_rearm() -> None:
    fabric = driving_fabric(timeout_ms=30)
    fabric.tick(20 * MS)
    write_ok(fabric, "watchdog", "KICK", KICK_MAGIC ^ 1)
    assert read_ok(fabric, "watchdog", "BAD_KICK_COUNT") == 1
    fabric.tick(10 * MS)
    assert fabric.hw_read_actuation().watchdog_expired


def test_watchdog_expires_after_the_reset_timeout_when_never_kicked() -> None:
    fabric = Fabric()
    write_ok(fabric, "pwm0", "DUTY_TICKS", 2500)
    write_ok(fabric, "pwm0", "CTRL", 0b01)
    assert fabric.hw_read_actuation().duty[0] == 1.0
    fabric.tick(99 * MS)
    assert read_ok(fabric, "watchdog", "REMAINING_US") == 1_000
    fabric.tick(1 * MS)
    assert fabric.hw_read_actuation().duty[0] == 0.0


def test_new_timeout_takes_effect_at_the_next_kick() -> None:
    fabric = Fabric()
    write_ok(fabric, "watchdog", "TIMEOUT_MS", 500)
    fabric.tick(99 * MS)
    assert not fabric.hw_read_actuation().watchdog_expired
    fabric.tick(1 * MS)
    assert fabric.hw_read_actuation().watchdog_expired
    write_ok(fabric, "watchdog", "KICK", KICK_MAGIC)
    fabric.tick(499 * MS)
    assert not fabric.hw_read_actuation().watchdog_expired


def test_disabled_watchdog_neither_counts_nor_cuts() -> None:
    fabric = driving_fabric(timeout_ms=10)
    fabric.tick(10 * MS)
    assert fabric.hw_read_actuation().watchdog_expired
    write_ok(fabric, "watchdog", "CTRL", 0)
    assert not fabric.hw_read_actuation().watchdog_expired
    fabric.tick(1000 * MS)
    assert fabric.hw_read_actuation().any_enabled
    assert read_ok(fabric, "watchdog", "STATUS") == 0
    write_ok(fabric, "watchdog", "CTRL", 1)
    assert read_ok(fabric, "watchdog", "REMAINING_US") == 10_000
    fabric.tick(10 * MS)
    assert fabric.hw_read_actuation().watchdog_expired

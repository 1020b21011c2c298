"""PLL and clock dividers: reconfiguration, lock delay, refused settings, consumers follow."""

from __future__ import annotations

from robot_firmware.fpga import Fabric
from robot_firmware.fpga.clock import LOCK_TIME_NS
from tests.fpga.register_sites import read_ok, write_ok

LOCKED, CFG_ERROR = 0b01, 0b10


def test_reset_clocks_are_derived_from_the_50_mhz_reference() -> None:
    fabric = Fabric()
    assert read_ok(fabric, "clock", "REF_HZ") == 50_000_000
    assert read_ok(fabric, "clock", "PLL_HZ") == 100_000_000
    assert read_ok(fabric, "clock", "C0_HZ") == 50_000_000
    assert read_ok(fabric, "clock", "C1_HZ") == 40_000
    assert read_ok(fabric, "clock", "STATUS") == LOCKED


def test_lock_flag_rises_some_microseconds_after_a_reconfiguration() -> None:
    fabric = Fabric()
    write_ok(fabric, "clock", "PLL_MULT", 8)
    write_ok(fabric, "clock", "PLL_DIV", 2)
    write_ok(fabric, "clock", "C0_DIV", 4)
    write_ok(fabric, "clock", "CTRL", 1)
    assert read_ok(fabric, "clock", "STATUS") == 0
    assert read_ok(fabric, "clock", "C0_HZ") == 50_000_000
    fabric.tick(LOCK_TIME_NS - 1)
    assert read_ok(fabric, "clock", "STATUS") == 0
    assert fabric.clock.hw_fabric_clock_hz() == 50_000_000
    fabric.tick(1)
    assert read_ok(fabric, "clock", "STATUS") == LOCKED
    assert read_ok(fabric, "clock", "PLL_HZ") == 200_000_000
    assert read_ok(fabric, "clock", "C0_HZ") == 50_000_000
    assert read_ok(fabric, "clock", "C1_HZ") == 80_000


def test_out_of_range_setting_is_refused_and_the_clocks_keep_running() -> None:
    fabric = Fabric()
    write_ok(fabric, "clock", "PLL_MULT", 63)  # 3.15 GHz
    write_ok(fabric, "clock", "CTRL", 1)
    assert read_ok(fabric, "clock", "STATUS") == LOCKED | CFG_ERROR
    fabric.tick(10 * LOCK_TIME_NS)
    assert read_ok(fabric, "clock", "PLL_HZ") == 100_000_000
    write_ok(fabric, "clock", "C0_DIV", 0)
    write_ok(fabric, "clock", "PLL_MULT", 2)
    write_ok(fabric, "clock", "CTRL", 1)
    assert read_ok(fabric, "clock", "STATUS") == LOCKED | CFG_ERROR
    write_ok(fabric, "clock", "C0_DIV", 1)
    write_ok(fabric, "clock", "CTRL", 1)
    assert read_ok(fabric, "clock", "STATUS") == 0


def test_sonar_counts_in_the_new_fabric_clock_after_lock() -> None:
    fabric = Fabric()
    write_ok(fabric, "clock", "C0_DIV", 1)  # C0 = 100 MHz
    write_ok(fabric, "clock", "CTRL", 1)
    fabric.tick(LOCK_TIME_NS)
    times: list[float | None] = [0.001] * len(fabric.sonar)
    fabric.hw_apply_sense([0, 0, 0, 0], times, None)
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(1_000_000)
    assert read_ok(fabric, "sonar0", "WIDTH_TICKS") == 100_000

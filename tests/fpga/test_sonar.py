"""Ultrasound: echo time from the world -> pulse width in fabric ticks -> data ready / timeout."""

from __future__ import annotations

import pytest

from robot_firmware.fpga import Fabric
from robot_firmware.fpga.digital_filter import FilterMode
from robot_firmware.fpga.sonar import (
    SPEED_OF_SOUND_MPS,
    echo_time_s_for_range_m,
    range_m_for_width_ticks,
)
from tests.fpga.register_sites import read_ok, write_ok

US = 1_000
MS = 1_000_000
FABRIC_HZ = 50_000_000
DATA_READY, TIMEOUT, MISSED = 0b001, 0b010, 0b100


def echoes(fabric: Fabric, echo_time_s: float | None, index: int = 0) -> None:
    times: list[float | None] = [None] * len(fabric.sonar)
    times[index] = echo_time_s
    fabric.hw_apply_sense([0, 0, 0, 0], times, None)


def test_echo_time_becomes_pulse_width_in_fabric_ticks_and_data_ready() -> None:
    fabric = Fabric()
    echo_s = echo_time_s_for_range_m(1.0)
    echoes(fabric, echo_s, index=3)
    write_ok(fabric, "sonar3", "TRIGGER", 1)
    assert read_ok(fabric, "sonar3", "STATUS") == 1
    fabric.tick(5 * MS)
    assert read_ok(fabric, "sonar3", "EVENTS") == 0
    fabric.tick(831 * US)
    assert read_ok(fabric, "sonar3", "EVENTS") == DATA_READY
    assert read_ok(fabric, "sonar3", "EVENTS") == 0  # read-to-clear
    assert read_ok(fabric, "sonar3", "STATUS") == 0
    width = read_ok(fabric, "sonar3", "WIDTH_TICKS")
    assert width == round(2.0 / SPEED_OF_SOUND_MPS * FABRIC_HZ) == 291_545
    assert range_m_for_width_ticks(width, FABRIC_HZ) == pytest.approx(1.0, abs=1e-5)
    assert read_ok(fabric, "sonar3", "SAMPLES") == 1
    assert read_ok(fabric, "sonar0", "SAMPLES") == 0


def test_no_echo_sets_the_timeout_flag_after_the_timeout() -> None:
    fabric = Fabric()
    echoes(fabric, None)
    write_ok(fabric, "sonar0", "TIMEOUT_TICKS", 1_000_000)  # 20 ms
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(19 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == 0
    fabric.tick(1 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == TIMEOUT
    assert read_ok(fabric, "sonar0", "WIDTH_TICKS") == 0
    assert read_ok(fabric, "sonar0", "SAMPLES") == 0


def test_echo_longer_than_the_timeout_is_a_timeout() -> None:
    fabric = Fabric()
    echoes(fabric, echo_time_s_for_range_m(6.0))  # 35 ms > 30 ms reset timeout
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(30 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == TIMEOUT


@pytest.mark.parametrize("echo_s", [3.6e300, 1e300])
def test_an_echo_too_long_for_any_count_of_ticks_is_a_timeout(echo_s: float) -> None:
    """Finite, but times the clock it overflows a float (or an int's range of ticks)."""
    fabric = Fabric()
    echoes(fabric, echo_s)
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(30 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == TIMEOUT
    assert read_ok(fabric, "sonar0", "WIDTH_TICKS") == 0


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1e-3])
def test_malformed_echo_time_counts_as_no_echo(bad: float) -> None:
    fabric = Fabric()
    echoes(fabric, bad)
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(30 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == TIMEOUT


def test_trigger_while_busy_is_ignored_and_flagged() -> None:
    fabric = Fabric()
    echoes(fabric, 0.004)
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    fabric.tick(1 * MS)
    echoes(fabric, 0.001)
    write_ok(fabric, "sonar0", "TRIGGER", 1)
    assert read_ok(fabric, "sonar0", "EVENTS") == MISSED
    fabric.tick(3 * MS)
    assert read_ok(fabric, "sonar0", "EVENTS") == DATA_READY
    assert read_ok(fabric, "sonar0", "WIDTH_TICKS") == 200_000


def test_filtered_width_goes_through_the_sonar_filter() -> None:
    fabric = Fabric()
    write_ok(fabric, "sonar_filter", "MODE", FilterMode.MEDIAN)
    write_ok(fabric, "sonar_filter", "WINDOW", 3)
    filtered = []
    for echo_ms in (2, 2, 20, 2, 3):  # one spurious long echo
        echoes(fabric, echo_ms / 1000, index=1)
        write_ok(fabric, "sonar1", "TRIGGER", 1)
        fabric.tick(echo_ms * MS)
        assert read_ok(fabric, "sonar1", "EVENTS") == DATA_READY
        filtered.append(read_ok(fabric, "sonar1", "FILTERED_TICKS") // 50_000)
    assert filtered == [2, 2, 2, 2, 3]  # the 20 ms spike never comes through
    assert read_ok(fabric, "sonar1", "WIDTH_TICKS") == 150_000

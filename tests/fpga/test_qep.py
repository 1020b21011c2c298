"""QEP: 4x counts from the pins to COUNT, signed wrap-around, overflow flag, clear, speed."""

from __future__ import annotations

from robot_firmware.fpga import Fabric, as_signed32
from robot_firmware.fpga.digital_filter import FilterMode
from tests.fpga.register_sites import read_ok, write_ok

MS = 1_000_000
OVERFLOW, SPEED_NEW = 0b01, 0b10


def sense(fabric: Fabric, counts: list[int]) -> None:
    fabric.hw_apply_sense(counts, [None] * len(fabric.sonar), None)


def test_encoder_counts_from_the_pins_appear_in_count() -> None:
    fabric = Fabric()
    sense(fabric, [1000, 2000, 3000, 4000])  # the first value is the power-up baseline
    assert [read_ok(fabric, f"qep{i}", "COUNT") for i in range(4)] == [0, 0, 0, 0]
    sense(fabric, [1000 + 4 * 360, 2000 - 8, 3000, 4001])
    counts = [as_signed32(read_ok(fabric, f"qep{i}", "COUNT")) for i in range(4)]
    assert counts == [1440, -8, 0, 1]
    assert [read_ok(fabric, f"qep{i}", "STATUS") for i in (0, 1, 3)] == [0, 1, 0]


def test_count_is_signed_twos_complement() -> None:
    fabric = Fabric()
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [-1, 0, 0, 0])
    assert read_ok(fabric, "qep0", "COUNT") == 0xFFFF_FFFF
    assert fabric.qep[0].hw_count() == -1


def test_count_wraps_at_32_bits_and_sets_the_overflow_flag() -> None:
    fabric = Fabric()
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [2**31 - 1, -(2**31), 0, 0])
    assert read_ok(fabric, "qep0", "COUNT") == 0x7FFF_FFFF
    assert read_ok(fabric, "qep0", "EVENTS") & OVERFLOW == 0
    assert read_ok(fabric, "qep1", "EVENTS") & OVERFLOW == 0
    sense(fabric, [2**31 + 1, -(2**31) - 1, 0, 0])
    assert as_signed32(read_ok(fabric, "qep0", "COUNT")) == -(2**31) + 1
    assert as_signed32(read_ok(fabric, "qep1", "COUNT")) == 2**31 - 1
    assert read_ok(fabric, "qep0", "EVENTS") & OVERFLOW
    assert read_ok(fabric, "qep1", "EVENTS") & OVERFLOW
    write_ok(fabric, "qep0", "EVENTS", OVERFLOW)
    assert read_ok(fabric, "qep0", "EVENTS") & OVERFLOW == 0
    assert read_ok(fabric, "qep1", "EVENTS") & OVERFLOW


def test_clear_zeroes_the_count_and_counting_continues() -> None:
    fabric = Fabric()
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [500, 500, 0, 0])
    write_ok(fabric, "qep0", "CLEAR", 1)
    assert read_ok(fabric, "qep0", "COUNT") == 0
    assert read_ok(fabric, "qep1", "COUNT") == 500
    sense(fabric, [520, 500, 0, 0])
    assert read_ok(fabric, "qep0", "COUNT") == 20


def test_clear_written_with_zero_changes_nothing() -> None:
    fabric = Fabric()
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [500, 0, 0, 0])
    write_ok(fabric, "qep0", "CLEAR", 0)
    assert read_ok(fabric, "qep0", "COUNT") == 500


def test_invert_and_enable_bits_shape_the_count() -> None:
    fabric = Fabric()
    write_ok(fabric, "qep0", "CTRL", 0b11)
    write_ok(fabric, "qep1", "CTRL", 0b00)
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [100, 100, 0, 0])
    assert as_signed32(read_ok(fabric, "qep0", "COUNT")) == -100
    assert read_ok(fabric, "qep1", "COUNT") == 0


def test_speed_is_latched_every_window_and_filtered() -> None:
    fabric = Fabric()
    write_ok(fabric, "speed_filter", "MODE", FilterMode.MOVING_AVERAGE)
    write_ok(fabric, "speed_filter", "WINDOW", 2)
    position = 0
    sense(fabric, [0, 0, 0, 0])
    speeds = []
    for per_window in (100, 300, -50):
        position += per_window
        sense(fabric, [position, 0, 0, 0])
        fabric.tick(9 * MS)
        assert read_ok(fabric, "qep0", "EVENTS") & SPEED_NEW == 0
        fabric.tick(1 * MS)  # the 10 ms window of the 50 MHz reset clock ends
        assert read_ok(fabric, "qep0", "EVENTS") & SPEED_NEW
        write_ok(fabric, "qep0", "EVENTS", SPEED_NEW)
        speeds.append(
            (
                as_signed32(read_ok(fabric, "qep0", "SPEED")),
                as_signed32(read_ok(fabric, "qep0", "SPEED_FILTERED")),
            )
        )
    assert speeds == [(100, 100), (300, 200), (-50, 125)]


def test_speed_over_several_windows_in_one_tick_is_the_mean_per_window() -> None:
    fabric = Fabric()
    sense(fabric, [0, 0, 0, 0])
    sense(fabric, [0, 0, 0, -300])
    fabric.tick(30 * MS)
    assert as_signed32(read_ok(fabric, "qep3", "SPEED")) == -100

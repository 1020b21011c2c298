"""Encoder driver: 32-bit QEP counts unwrapped into running int64 counts, and windowed speeds."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from robot_firmware.drivers.encoders import EncoderDriver
from robot_firmware.fpga import Fabric, as_signed32

MS = 1_000_000
WRAP = 1 << 32


def apply_counts(fabric: Fabric, counts: Sequence[int]) -> None:
    fabric.hw_apply_sense(list(counts), [None] * len(fabric.sonar), None)


def test_counts_equal_what_the_world_applied() -> None:
    fabric = Fabric()
    encoders = EncoderDriver(fabric.bus)
    apply_counts(fabric, [0, 0, 0, 0])
    apply_counts(fabric, [10, -20, 30_000, -40_000])
    counts = encoders.read_counts()
    assert counts.dtype == np.int64
    assert counts.shape == (4,)
    assert counts.tolist() == [10, -20, 30_000, -40_000]
    assert encoders.bus_errors == 0


def test_counts_unwrap_across_the_32_bit_boundary_both_ways() -> None:
    fabric = Fabric()
    encoders = EncoderDriver(fabric.bus)
    apply_counts(fabric, [0, 0, 0, 0])
    top = (1 << 31) - 10
    path = [
        [top, -top, 5, 0],
        [top + 100, -top - 100, 5, 0],  # wheels 0 and 1 wrap between these reads
        [top + 2**31, -top - 2**31, 5, 0],
        [top + 2**31 - 3, -top - 2**31 + 3, 5, 0],
    ]
    for step in path:
        apply_counts(fabric, step)
        assert encoders.read_counts().tolist() == step
    word = fabric.bus.read(fabric.bus.address_of("qep0", "COUNT")).value
    assert word == (top + 2**31 - 3) % WRAP
    assert as_signed32(word) == -13
    assert (fabric.bus.read(fabric.bus.address_of("qep0", "EVENTS")).value & 1) == 1  # OVERFLOW


def test_counts_keep_running_over_many_reads() -> None:
    fabric = Fabric()
    encoders = EncoderDriver(fabric.bus)
    apply_counts(fabric, [0, 0, 0, 0])
    step = 900_000_000
    for n in range(1, 13):
        apply_counts(fabric, [n * step, -n * step, n, 0])
        counts = encoders.read_counts()
    assert counts.tolist() == [12 * step, -12 * step, 12, 0]
    assert counts[0] > 2**33


def test_first_read_starts_from_the_register_value() -> None:
    fabric = Fabric()
    apply_counts(fabric, [0, 0, 0, 0])
    apply_counts(fabric, [-5, 7, 0, 0])
    encoders = EncoderDriver(fabric.bus)
    assert encoders.read_counts().tolist() == [-5, 7, 0, 0]


def test_speed_is_counts_per_window_scaled_to_counts_per_second() -> None:
    fabric = Fabric()
    encoders = EncoderDriver(fabric.bus)
    assert encoders.read_speeds_counts_per_s().tolist() == [0.0] * 4
    apply_counts(fabric, [0, 0, 0, 0])
    apply_counts(fabric, [1_000, -250, 0, 3])
    fabric.tick(10 * MS)  # one 10 ms speed window at the reset clock
    speeds = encoders.read_speeds_counts_per_s()
    assert speeds.dtype == np.float64
    assert speeds == pytest.approx([100_000.0, -25_000.0, 0.0, 300.0])


def test_wheel_count_outside_the_map_is_refused() -> None:
    with pytest.raises(ValueError, match="wheel_count"):
        EncoderDriver(Fabric().bus, wheel_count=5)

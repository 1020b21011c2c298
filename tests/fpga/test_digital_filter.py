"""Digital filter: moving average and median over a known sequence, configured by registers."""

from __future__ import annotations

import pytest

from robot_firmware.fpga import digital_filter as regs
from robot_firmware.fpga.digital_filter import (
    DigitalFilter,
    FilterMode,
    median,
    moving_average,
)

MODE = regs.MODE.offset
WINDOW = regs.WINDOW.offset
STATUS = regs.STATUS.offset
FLUSH = regs.FLUSH.offset
SEQUENCE = [10, 20, 90, 30, 40, -60, 50]


def run(mode: FilterMode, window: int, samples: list[int]) -> list[int]:
    digital_filter = DigitalFilter("f", channels=2)
    digital_filter.write(MODE, mode)
    digital_filter.write(WINDOW, window)
    return [digital_filter.hw_filter(1, s) for s in samples]


def test_moving_average_over_a_known_sequence() -> None:
    # windows: [10] [10 20] [10 20 90] [20 90 30] [90 30 40] [30 40 -60] [40 -60 50]
    assert run(FilterMode.MOVING_AVERAGE, 3, SEQUENCE) == [10, 15, 40, 46, 53, 3, 10]


def test_median_over_a_known_sequence() -> None:
    assert run(FilterMode.MEDIAN, 3, SEQUENCE) == [10, 10, 20, 30, 40, 30, 40]


def test_bypass_passes_samples_through() -> None:
    assert run(FilterMode.BYPASS, 8, SEQUENCE) == SEQUENCE


def test_moving_average_truncates_toward_zero() -> None:
    assert moving_average([-1, -2]) == -1
    assert moving_average([1, 2]) == 1
    assert run(FilterMode.MOVING_AVERAGE, 2, [-7, 0]) == [-7, -3]


def test_median_of_an_even_count_is_the_lower_middle() -> None:
    assert median([4, 1, 3, 2]) == 2


def test_channels_keep_separate_histories() -> None:
    digital_filter = DigitalFilter("f", channels=2)
    digital_filter.write(MODE, FilterMode.MOVING_AVERAGE)
    digital_filter.write(WINDOW, 4)
    digital_filter.hw_filter(0, 1000)
    assert digital_filter.hw_filter(1, 10) == 10
    assert digital_filter.hw_filter(0, 0) == 500


@pytest.mark.parametrize(
    ("mode", "window", "status"),
    [
        (FilterMode.MEDIAN, 5, (2 << 8) | 5),
        (FilterMode.MOVING_AVERAGE, 0, (1 << 8) | 1),
        (FilterMode.MOVING_AVERAGE, 31, (1 << 8) | 16),
        (3, 4, (0 << 8) | 4),
    ],
)
def test_status_shows_the_setting_in_effect(mode: int, window: int, status: int) -> None:
    digital_filter = DigitalFilter("f", channels=1)
    digital_filter.write(MODE, mode)
    digital_filter.write(WINDOW, window)
    assert digital_filter.read(STATUS) == status


def test_flush_and_reconfiguration_empty_the_history() -> None:
    digital_filter = DigitalFilter("f", channels=1)
    digital_filter.write(MODE, FilterMode.MOVING_AVERAGE)
    digital_filter.write(WINDOW, 4)
    digital_filter.hw_filter(0, 100)
    digital_filter.write(FLUSH, 1)
    assert digital_filter.hw_filter(0, 0) == 0
    digital_filter.write(WINDOW, 4)
    assert digital_filter.hw_filter(0, 8) == 8

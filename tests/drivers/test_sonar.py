"""Sonar driver: echo times on the pins become gaps in metres, fresh once, inf without an echo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_firmware.drivers.sonar import SonarDriver
from robot_firmware.fpga import Fabric, FabricConfig
from robot_firmware.fpga.digital_filter import FilterMode
from robot_firmware.fpga.sonar import SPEED_OF_SOUND_MPS, echo_time_s_for_range_m

MS = 1_000_000
FABRIC_HZ = 50_000_000
RESOLUTION_M = SPEED_OF_SOUND_MPS / FABRIC_HZ / 2.0  # one fabric tick of echo width
TIMEOUT_NS = 31 * MS  # the reset TIMEOUT_TICKS is 30 ms


def echoes_for(gaps_m: list[float | None]) -> list[float | None]:
    return [None if gap is None else echo_time_s_for_range_m(gap) for gap in gaps_m]


def measure(fabric: Fabric, sonar: SonarDriver, gaps_m: list[float | None]) -> None:
    fabric.hw_apply_sense([0, 0, 0, 0], echoes_for(gaps_m), None)
    sonar.trigger_all()
    fabric.tick(TIMEOUT_NS)


def test_poll_returns_the_gaps_after_trigger_and_then_reports_nothing_new() -> None:
    fabric = Fabric(FabricConfig(n_sonar=4))
    sonar = SonarDriver(fabric.bus, sonar_count=4)
    gaps_m: list[float | None] = [0.25, 1.0, None, 4.9]
    measure(fabric, sonar, gaps_m)
    readings_m, fresh = sonar.poll()
    assert fresh
    assert readings_m.dtype == np.float64
    assert readings_m.shape == (4,)
    assert readings_m[[0, 1, 3]] == pytest.approx([0.25, 1.0, 4.9], abs=RESOLUTION_M)
    assert math.isinf(readings_m[2])
    again_m, fresh = sonar.poll()
    assert not fresh
    np.testing.assert_array_equal(again_m, readings_m)
    assert sonar.bus_errors == 0


def test_readings_that_did_not_update_keep_their_value() -> None:
    fabric = Fabric(FabricConfig(n_sonar=2))
    sonar = SonarDriver(fabric.bus, sonar_count=2)
    measure(fabric, sonar, [0.5, 2.0])
    sonar.poll()
    fabric.hw_apply_sense([0, 0, 0, 0], echoes_for([0.8, 3.0]), None)
    fabric.bus.write(fabric.bus.address_of("sonar0", "TRIGGER"), 1)
    fabric.tick(TIMEOUT_NS)
    readings_m, fresh = sonar.poll()
    assert fresh
    assert readings_m == pytest.approx([0.8, 2.0], abs=RESOLUTION_M)


def test_no_echo_gives_inf_and_is_fresh() -> None:
    fabric = Fabric(FabricConfig(n_sonar=1))
    sonar = SonarDriver(fabric.bus, sonar_count=1)
    measure(fabric, sonar, [1.5])
    assert sonar.poll()[0][0] == pytest.approx(1.5, abs=RESOLUTION_M)
    measure(fabric, sonar, [None])
    readings_m, fresh = sonar.poll()
    assert fresh
    assert readings_m[0] == np.inf


def test_nothing_is_fresh_while_the_rangers_are_still_measuring() -> None:
    fabric = Fabric(FabricConfig(n_sonar=1))
    sonar = SonarDriver(fabric.bus, sonar_count=1)
    fabric.hw_apply_sense([0, 0, 0, 0], echoes_for([3.0]), None)
    sonar.trigger_all()
    fabric.tick(10 * MS)  # the echo of 3 m takes about 17.5 ms
    readings_m, fresh = sonar.poll()
    assert not fresh
    assert readings_m[0] == np.inf  # nothing measured yet
    fabric.tick(10 * MS)
    assert sonar.poll()[1]


def test_trigger_while_busy_is_counted_as_missed() -> None:
    fabric = Fabric(FabricConfig(n_sonar=1))
    sonar = SonarDriver(fabric.bus, sonar_count=1)
    fabric.hw_apply_sense([0, 0, 0, 0], echoes_for([2.0]), None)
    sonar.trigger_all()
    sonar.trigger_all()
    fabric.tick(TIMEOUT_NS)
    readings_m, fresh = sonar.poll()
    assert fresh
    assert readings_m[0] == pytest.approx(2.0, abs=RESOLUTION_M)
    assert sonar.missed_triggers == 1


def test_median_filter_removes_a_single_outlier() -> None:
    fabric = Fabric(FabricConfig(n_sonar=1))
    sonar = SonarDriver(fabric.bus, sonar_count=1)
    assert sonar.configure_filter(FilterMode.MEDIAN, 3)
    for gap_m in (1.0, 1.02, 0.2):
        measure(fabric, sonar, [gap_m])
        readings_m, fresh = sonar.poll()
        assert fresh
    assert readings_m[0] == pytest.approx(1.0, abs=RESOLUTION_M)
    assert sonar.configure_filter()  # back to bypass
    measure(fabric, sonar, [0.2])
    assert sonar.poll()[0][0] == pytest.approx(0.2, abs=RESOLUTION_M)


def test_gap_uses_the_fabric_clock_of_the_trigger() -> None:
    fabric = Fabric(FabricConfig(n_sonar=1))
    bus = fabric.bus
    bus.write(bus.address_of("clock", "C0_DIV"), 5)  # 100 MHz / 5 = 20 MHz
    bus.write(bus.address_of("clock", "CTRL"), 1)
    fabric.tick(20_000)
    sonar = SonarDriver(bus, sonar_count=1)
    measure(fabric, sonar, [1.234])
    assert sonar.poll()[0][0] == pytest.approx(1.234, abs=SPEED_OF_SOUND_MPS / 20e6)


def test_filter_window_outside_the_block_is_refused() -> None:
    sonar = SonarDriver(Fabric().bus, sonar_count=12)
    with pytest.raises(ValueError, match="window"):
        sonar.configure_filter(FilterMode.MOVING_AVERAGE, 17)

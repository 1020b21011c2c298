"""Refused bus accesses are counted by the drivers and never raised; a typical tick stays cheap."""

from __future__ import annotations

import numpy as np
import pytest

from robot_firmware.drivers import Drivers
from robot_firmware.drivers.encoders import EncoderDriver
from robot_firmware.drivers.motors import MotorDriver
from robot_firmware.drivers.positioning import PositioningDriver
from robot_firmware.drivers.sonar import SonarDriver
from robot_firmware.drivers.watchdog import WatchdogDriver
from robot_firmware.fpga import Bus, BusErrorKind, BusOp, Fabric, FabricConfig, RecordingBus
from robot_firmware.fpga.sonar import echo_time_s_for_range_m

MS = 1_000_000


def test_sonar_driver_for_more_rangers_than_the_image_has_keeps_the_mapped_ones() -> None:
    fabric = Fabric(FabricConfig(n_sonar=2))
    sonar = SonarDriver(fabric.bus, sonar_count=4)
    fabric.hw_apply_sense([0, 0, 0, 0], [echo_time_s_for_range_m(0.5), None], None)
    sonar.trigger_all()
    assert sonar.bus_errors == 2  # TRIGGER of sonar2 and sonar3
    fabric.tick(31 * MS)
    readings_m, fresh = sonar.poll()
    assert fresh
    assert readings_m[0] == pytest.approx(0.5, abs=1e-5)
    assert readings_m[1:].tolist() == [np.inf] * 3
    assert sonar.bus_errors == 4  # and their EVENTS
    assert fabric.bus.error_counts[BusErrorKind.UNMAPPED] == 4


def test_every_per_tick_method_survives_a_bus_with_nothing_mapped() -> None:
    bus = Bus()
    drivers = Drivers.attach(bus, sonar_count=3)
    drivers.motors.configure()
    drivers.watchdog.configure(100)
    drivers.sonar.trigger_all()
    for _ in range(3):
        assert drivers.encoders.read_counts().tolist() == [0, 0, 0, 0]
        assert np.isnan(drivers.encoders.read_speeds_counts_per_s()).all()
        readings_m, fresh = drivers.sonar.poll()
        assert not fresh
        assert readings_m.tolist() == [np.inf] * 3
        assert drivers.positioning.read_fix() is None
        drivers.motors.set_duty([0.5, -0.5, 0.0, 0.1])
        drivers.watchdog.kick()
        assert not drivers.watchdog.expired()
    assert drivers.motors.last_duty == (0.5, -0.5, 0.0, 0.1)
    assert drivers.bus_errors == bus.error_total > 0


def test_motor_writes_refused_once_are_written_again_next_tick() -> None:
    motors = MotorDriver(Bus())
    motors.set_duty([0.5, 0.0, 0.0, 0.0])
    first = motors.bus_errors
    motors.set_duty([0.5, 0.0, 0.0, 0.0])
    assert first == 8
    assert motors.bus_errors == 2 * first


def test_encoder_keeps_its_running_count_across_a_refused_read() -> None:
    fabric = Fabric()
    encoders = EncoderDriver(fabric.bus)
    fabric.hw_apply_sense([0, 0, 0, 0], [None] * 12, None)
    fabric.hw_apply_sense([100, 0, 0, 0], [None] * 12, None)
    assert encoders.read_counts()[0] == 100
    broken = EncoderDriver(Bus())
    assert broken.read_counts().tolist() == [0, 0, 0, 0]
    assert broken.bus_errors == 4


def test_watchdog_repeats_its_last_state_when_status_cannot_be_read() -> None:
    watchdog = WatchdogDriver(Bus())
    assert not watchdog.expired()
    assert watchdog.bus_errors == 1


def test_positioning_gives_none_when_the_receiver_cannot_be_read() -> None:
    positioning = PositioningDriver(Bus())
    assert positioning.read_fix() is None
    assert positioning.bus_errors == 1


def test_typical_control_tick_bus_accesses() -> None:
    bus = RecordingBus()
    fabric = Fabric(bus=bus)
    drivers = Drivers.attach(bus, sonar_count=12)
    drivers.system.identify()
    drivers.motors.configure()
    drivers.watchdog.configure(100)
    drivers.encoders.read_counts()
    drivers.sonar.poll()
    drivers.positioning.read_fix()
    drivers.motors.set_duty([0.1, 0.2, 0.3, 0.4])
    bus.clear()

    drivers.encoders.read_counts()
    drivers.sonar.poll()
    drivers.positioning.read_fix()
    drivers.motors.set_duty([0.1, 0.2, 0.3, 0.4])
    drivers.watchdog.kick()
    reads = sum(a.op is BusOp.READ for a in bus.accesses)
    writes = sum(a.op is BusOp.WRITE for a in bus.accesses)
    assert (reads, writes) == (4 + 12 + 1, 1)  # steady command: only the kick is written
    assert fabric.bus.error_total == 0

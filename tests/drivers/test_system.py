"""System probe: identifies the image and its counts, refuses a foreign one, awaits PLL lock."""

from __future__ import annotations

import pytest

from robot_firmware.drivers.system import (
    SUPPORTED_VERSION_MAJOR,
    IncompatibleFabricError,
    SystemProbe,
)
from robot_firmware.fpga import Bus, Fabric, FabricConfig
from robot_firmware.fpga import sysid as sysid_map


def test_identify_reports_the_image_and_its_instance_counts() -> None:
    fabric = Fabric(FabricConfig(n_sonar=7))
    info = SystemProbe(fabric.bus).identify()
    assert info.system_id == 0x5357_524D
    assert (info.version_major, info.version_minor, info.version_patch) == (1, 0, 0)
    assert info.version == "1.0.0"
    assert info.build == 1
    assert (info.n_qep, info.n_pwm, info.n_sonar) == (4, 4, 7)


def test_wrong_system_id_is_incompatible() -> None:
    fabric = Fabric()
    fabric.sysid.hw_force(sysid_map.ID.offset, 0xDEAD_BEEF)
    with pytest.raises(IncompatibleFabricError, match="0xdeadbeef"):
        SystemProbe(fabric.bus).identify()


def test_other_major_version_is_incompatible_but_a_newer_minor_is_not() -> None:
    fabric = Fabric()
    probe = SystemProbe(fabric.bus)
    fabric.sysid.hw_force(sysid_map.VERSION.offset, (SUPPORTED_VERSION_MAJOR + 1) << 24)
    with pytest.raises(IncompatibleFabricError, match="major version"):
        probe.identify()
    fabric.sysid.hw_force(sysid_map.VERSION.offset, (SUPPORTED_VERSION_MAJOR << 24) | (3 << 16))
    assert probe.identify().version_minor == 3


def test_bus_without_a_system_id_is_incompatible() -> None:
    probe = SystemProbe(Bus())
    with pytest.raises(IncompatibleFabricError, match="cannot be read"):
        probe.identify()
    assert probe.bus_errors == 1


def test_pll_lock_is_awaited_by_letting_fabric_time_pass() -> None:
    fabric = Fabric()
    bus = fabric.bus
    probe = SystemProbe(bus)
    assert probe.wait_for_pll_lock(fabric.tick, timeout_ns=0)  # locked at reset
    bus.write(bus.address_of("clock", "PLL_MULT"), 3)
    bus.write(bus.address_of("clock", "CTRL"), 1)
    start_ns = fabric.now_ns
    assert probe.wait_for_pll_lock(fabric.tick, timeout_ns=1_000_000)
    assert 20_000 <= fabric.now_ns - start_ns <= 21_000  # the 20 us lock time, polled every 1 us
    assert bus.read(bus.address_of("clock", "C0_HZ")).value == 75_000_000


def test_pll_lock_wait_times_out() -> None:
    fabric = Fabric()
    bus = fabric.bus
    bus.write(bus.address_of("clock", "PLL_MULT"), 3)
    bus.write(bus.address_of("clock", "CTRL"), 1)
    start_ns = fabric.now_ns
    assert not SystemProbe(bus).wait_for_pll_lock(fabric.tick, timeout_ns=5_000)
    assert fabric.now_ns - start_ns == 5_000

"""The fabric: address map, wiring, and the hardware side offered to the world."""

from __future__ import annotations

import pydantic
import pytest

from robot_firmware.fpga import Fabric, FabricConfig, PositionFix
from robot_firmware.fpga import address_map as amap
from tests.fpga.register_sites import read_ok


def test_peripherals_sit_at_the_documented_bases() -> None:
    fabric = Fabric()
    bases = {p.name: base for base, p in fabric.bus.mapped()}
    assert bases["sysid"] == amap.BRIDGE_BASE == 0xFF20_0000
    assert bases["clock"] == amap.CLOCK_BASE
    assert bases["watchdog"] == amap.WATCHDOG_BASE
    assert bases["positioning"] == amap.POSITIONING_BASE
    assert [bases[f"qep{i}"] for i in range(4)] == list(amap.QEP_BASES)
    assert [bases[f"pwm{i}"] for i in range(4)] == list(amap.PWM_BASES)
    assert bases["sonar_filter"] == amap.SONAR_FILTER_BASE
    assert bases["speed_filter"] == amap.SPEED_FILTER_BASE
    assert [bases[f"sonar{i}"] for i in range(12)] == [amap.sonar_base(i) for i in range(12)]
    assert all(
        amap.BRIDGE_BASE <= base < amap.BRIDGE_BASE + amap.BRIDGE_SPAN_BYTES
        for base in bases.values()
    )


def test_sonar_count_is_configurable_and_reported_in_caps() -> None:
    fabric = Fabric(FabricConfig(n_sonar=16))
    assert len(fabric.sonar) == 16
    assert read_ok(fabric, "sysid", "CAPS") == 4 | (4 << 4) | (16 << 8)
    assert read_ok(fabric, "sonar15", "STATUS") == 0
    assert read_ok(Fabric(), "sysid", "CAPS") >> 8 == 12


@pytest.mark.parametrize("n_sonar", [0, 17])
def test_sonar_count_outside_the_map_is_refused(n_sonar: int) -> None:
    with pytest.raises(pydantic.ValidationError):
        FabricConfig(n_sonar=n_sonar)


def test_sense_message_of_the_wrong_shape_is_refused_and_changes_nothing() -> None:
    fabric = Fabric()
    fabric.hw_apply_sense([0, 0, 0, 0], [None] * 12, None)
    before = fabric.bus.snapshot()
    with pytest.raises(ValueError, match="encoder counts"):
        fabric.hw_apply_sense([1, 2, 3], [None] * 12, None)
    with pytest.raises(ValueError, match="echo times"):
        fabric.hw_apply_sense([1, 2, 3, 4], [None] * 11, PositionFix(1, 1, 0, 1))
    with pytest.raises(ValueError, match="integers"):
        fabric.hw_apply_sense([1, 2, 3, 4.5], [None] * 12, PositionFix(1, 1, 0, 1))  # type: ignore[list-item]
    assert fabric.bus.snapshot() == before


def test_time_only_runs_forward() -> None:
    fabric = Fabric()
    fabric.tick(5)
    with pytest.raises(ValueError, match="forward"):
        fabric.tick(-1)
    assert fabric.now_ns == 5


def test_fresh_fabric_drives_nothing() -> None:
    actuation = Fabric().hw_read_actuation()
    assert actuation.duty == (0.0, 0.0, 0.0, 0.0)
    assert actuation.enabled == (False, False, False, False)
    assert not actuation.watchdog_expired


def test_every_register_word_is_a_plain_integer_at_reset() -> None:
    """Not a subclass of int such as an IntEnum: a register holds bits (and the compiled
    register model, robot_firmware/native.py, stores plain integers)."""
    words = Fabric().bus.snapshot()
    assert words and {type(word) for word in words.values()} == {int}

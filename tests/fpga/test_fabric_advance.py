"""`Fabric.advance` merges quiet fabric slices and leaves the state of one tick per slice.

Two fabrics get the same pins and bus writes; one advances with `advance`, the other with a
`tick` per slice (the last one shorter).  Every register word and every scalar of every IP's
hidden state (countdowns, windows, echo results) must agree after every step, so a merge that
skipped an event, or ticked an IP with another's state of a later slice, fails here.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_firmware.fpga import Fabric, PositionFix
from robot_firmware.fpga.clock import CTRL_APPLY
from robot_firmware.fpga.qep import CTRL_EN as QEP_EN
from robot_firmware.fpga.qep import CTRL_INVERT as QEP_INVERT
from robot_firmware.fpga.registers import Peripheral, slices_before_due
from robot_firmware.fpga.watchdog import KICK_MAGIC

N_SONAR = 12
MS = 1_000_000


def tick_per_slice(fabric: Fabric, dt_ns: int, slice_ns: int) -> None:
    """The specification: one `tick` per slice, the last one shorter."""
    while dt_ns > 0:
        step_ns = min(slice_ns, dt_ns)
        fabric.tick(step_ns)
        dt_ns -= step_ns


def attributes(instance: object) -> dict[str, Any]:
    """An instance's attributes: its `__dict__`, or, compiled by mypyc (robot_firmware/native.py),
    the attributes its class declares."""
    if hasattr(instance, "__dict__"):
        return vars(instance)
    return {name: getattr(instance, name) for name in type(instance).__mypyc_attrs__}  # type: ignore[attr-defined]


def state(fabric: Fabric) -> dict[str, Any]:
    """Every register word, and every scalar attribute of every IP (its hidden timers)."""
    scalars = (int, float, bool, str, type(None))
    ips = {
        peripheral.name: {k: v for k, v in attributes(peripheral).items() if isinstance(v, scalars)}
        for peripheral in fabric.peripherals
    }
    return {"now_ns": fabric.now_ns, "words": fabric.bus.snapshot(), "ips": ips}


def write(fabric: Fabric, peripheral: str, register: str, value: int) -> None:
    """A bus write as the firmware makes it; a refused one is part of the test too."""
    fabric.bus.write(fabric.bus.address_of(peripheral, register), value & 0xFFFF_FFFF)


echo_times = st.one_of(st.none(), st.floats(0.0, 0.04))
fixes = st.one_of(
    st.none(),
    st.builds(
        PositionFix,
        st.floats(-5, 5),
        st.floats(-5, 5),
        st.floats(-3, 3),
        st.integers(0, 10**9),
        st.booleans(),
    ),
)
sense_ops = st.tuples(
    st.just("sense"),
    st.lists(st.integers(-5000, 5000), min_size=4, max_size=4),
    st.lists(echo_times, min_size=N_SONAR, max_size=N_SONAR),
    fixes,
)
write_ops = st.one_of(
    st.tuples(st.just("write"), st.just("watchdog"), st.just("KICK"), st.just(KICK_MAGIC)),
    st.tuples(st.just("write"), st.just("watchdog"), st.just("CTRL"), st.integers(0, 1)),
    st.tuples(st.just("write"), st.just("watchdog"), st.just("TIMEOUT_MS"), st.integers(0, 60)),
    st.tuples(
        st.just("write"),
        st.sampled_from([f"sonar{i}" for i in range(N_SONAR)]),
        st.just("TRIGGER"),
        st.just(1),
    ),
    st.tuples(
        st.just("write"),
        st.sampled_from([f"sonar{i}" for i in range(N_SONAR)]),
        st.just("TIMEOUT_TICKS"),
        st.integers(0, 2_000_000),
    ),
    st.tuples(
        st.just("write"),
        st.sampled_from([f"qep{i}" for i in range(4)]),
        st.just("WINDOW_TICKS"),
        st.integers(0, 1_200_000),
    ),
    st.tuples(
        st.just("write"),
        st.sampled_from([f"qep{i}" for i in range(4)]),
        st.just("CTRL"),
        st.sampled_from([0, QEP_EN.insert(0, 1), QEP_EN.insert(QEP_INVERT.insert(0, 1), 1)]),
    ),
    st.tuples(st.just("write"), st.just("positioning"), st.just("STALE_MS"), st.integers(0, 40)),
    st.tuples(st.just("write"), st.just("clock"), st.just("PLL_MULT"), st.integers(1, 8)),
    st.tuples(st.just("write"), st.just("clock"), st.just("C0_DIV"), st.integers(1, 4)),
    st.tuples(
        st.just("write"), st.just("clock"), st.just("CTRL"), st.just(CTRL_APPLY.insert(0, 1))
    ),
)
advance_ops = st.tuples(
    st.just("advance"),
    st.builds(
        lambda whole_ms, extra_ns: whole_ms * MS + extra_ns,
        st.sampled_from(range(46)),  # spread over the range, not shrunk towards 0
        st.sampled_from([0, 0, 1, 6_999, MS // 2]),
    ),
)
operations = st.lists(
    st.one_of(sense_ops, sense_ops, write_ops, advance_ops, advance_ops), min_size=10, max_size=60
)


@settings(max_examples=200, deadline=None)
@given(ops=operations, slice_ns=st.sampled_from([MS, MS // 4, 3 * MS, 7_000]))
def test_advance_equals_one_tick_per_slice(ops: list[tuple[Any, ...]], slice_ns: int) -> None:
    merged, sliced = Fabric(), Fabric()
    for op in ops:
        for fabric in (merged, sliced):
            if op[0] == "sense":
                fabric.hw_apply_sense(op[1], op[2], op[3])
            elif op[0] == "write":
                write(fabric, op[1], op[2], op[3])
        if op[0] == "advance":
            merged.advance(op[1], slice_ns)
            tick_per_slice(sliced, op[1], slice_ns)
        assert state(merged) == state(sliced)


class CountingFabric(Fabric):
    def __init__(self) -> None:
        super().__init__()
        self.ticks = 0

    def tick(self, dt_ns: int) -> None:
        self.ticks += 1
        super().tick(dt_ns)


def test_a_control_period_with_one_window_and_one_echo_takes_a_few_ticks() -> None:
    """Ten 1 ms slices of a robot's period, a QEP window closing in the last one and an echo
    due in the fourth: ticked as the quiet run before the echo, the echo's slice, the quiet run
    before the window and the window's slice."""
    fabric = CountingFabric()
    fabric.advance(10 * MS, MS)  # the QEP windows (10 ms at reset) now close every 10 ms
    fabric.hw_apply_sense([0, 0, 0, 0], [3.5e-3] + [None] * (N_SONAR - 1), None)
    write(fabric, "sonar0", "TRIGGER", 1)
    fabric.ticks = 0
    fabric.advance(10 * MS, MS)
    assert fabric.ticks == 4
    assert fabric.now_ns == 20 * MS


def test_slices_before_due() -> None:
    assert slices_before_due(0, MS) == 0
    assert slices_before_due(-5, MS) == 0
    assert slices_before_due(1, MS) == 0
    assert slices_before_due(MS, MS) == 0
    assert slices_before_due(MS + 1, MS) == 1
    assert slices_before_due(10 * MS, MS) == 9


def test_every_ip_with_a_tick_says_when_it_is_next_due() -> None:
    """An IP that overrides `tick` without `quiet_slices` would be merged over its events."""
    ticking = {type(p) for p in Fabric().peripherals if type(p).tick is not Peripheral.tick}
    assert ticking, "the fabric has IPs that keep time"
    assert all(cls.quiet_slices is not Peripheral.quiet_slices for cls in ticking)


def test_a_slice_of_no_time_is_refused() -> None:
    with pytest.raises(ValueError, match="slice"):
        Fabric().advance(MS, 0)

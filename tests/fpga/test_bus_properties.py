"""Property tests: random bus traffic never escapes the bus and changes only what it may."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_firmware.fpga import Access, BusErrorKind, Fabric, PositionFix, qep, sonar
from robot_firmware.fpga.address_map import BRIDGE_BASE
from robot_firmware.fpga.watchdog import KICK_MAGIC
from tests.fpga.register_sites import ALL_SITES, RegisterSite

SITE_BY_ADDRESS: dict[int, RegisterSite] = {site.address: site for site in ALL_SITES}
MAPPED = sorted(SITE_BY_ADDRESS)
PWM_STATUS = {
    site.address
    for site in ALL_SITES
    if site.id.startswith("pwm") and site.register.name == "STATUS"
}

WRITABLE = sorted(site.address for site in ALL_SITES if site.register.access.writable)

addresses = st.one_of(
    st.sampled_from(MAPPED),
    st.sampled_from(WRITABLE),
    st.tuples(st.sampled_from(MAPPED), st.integers(1, 3)).map(sum),
    st.integers(BRIDGE_BASE - 0x10, BRIDGE_BASE + 0x2000),
    st.integers(-(1 << 33), 1 << 40),
)
values = st.one_of(
    st.integers(0, 0xFFFF_FFFF),
    st.sampled_from([0, 1, 0xFFFF_FFFF, KICK_MAGIC]),
    st.integers(-(1 << 40), 1 << 40),
)
accesses = st.tuples(st.sampled_from(["read", "write"]), addresses, values)


def expected_error(op: str, address: int, value: int) -> BusErrorKind | None:
    """The bus error an access must give, worked out from the declarations alone."""
    if address % 4:
        return BusErrorKind.MISALIGNED
    site = SITE_BY_ADDRESS.get(address)
    if site is None:
        return BusErrorKind.UNMAPPED
    access = site.register.access
    if op == "read":
        return None if access.readable else BusErrorKind.READ_OF_WRITE_ONLY
    if not 0 <= value <= 0xFFFF_FFFF:
        return BusErrorKind.VALUE_OUT_OF_RANGE
    return None if access.writable else BusErrorKind.WRITE_TO_READ_ONLY


def busy_fabric(warmup_ms: int) -> Fabric:
    """A fabric whose hardware side has state to lose: counts, echoes, a fix, elapsed time."""
    fabric = Fabric()
    n_sonar = len(fabric.sonar)
    fabric.hw_apply_sense([0, 0, 0, 0], [None] * n_sonar, None)
    fabric.hw_apply_sense(
        [5, -7, 1 << 31, 3], [0.002] * n_sonar, PositionFix(1.0, -2.0, 0.5, stamp_ns=1)
    )
    for ranger in fabric.sonar[:3]:
        ranger.hw_force(sonar.EVENTS.offset, 0b111)
    fabric.qep[0].hw_force(qep.EVENTS.offset, 0b11)
    fabric.tick(warmup_ms * 1_000_000)
    return fabric


@settings(max_examples=150, deadline=None)
@given(ops=st.lists(accesses, min_size=5, max_size=60), warmup_ms=st.integers(0, 150))
def test_random_accesses_never_raise_and_change_only_what_they_may(
    ops: list[tuple[str, int, int]], warmup_ms: int
) -> None:
    fabric = busy_fabric(warmup_ms)
    bus = fabric.bus
    for op, address, value in ops:
        before = bus.snapshot()
        errors_before = dict(bus.error_counts)
        result = bus.read(address) if op == "read" else bus.write(address, value)
        after = bus.snapshot()
        changed = {a for a in after if after[a] != before[a]}

        assert result.error is expected_error(op, address, value)
        if result.error is not None:
            errors_before[result.error] += 1
            assert dict(bus.error_counts) == errors_before
            assert changed == set()
            assert result.value == 0 or op == "write"
            continue
        assert dict(bus.error_counts) == errors_before

        site = SITE_BY_ADDRESS[address]
        reg = site.register
        if op == "read":
            assert result.value == before[address]
            assert changed <= ({address} if reg.access is Access.RC else set())
            if reg.access is Access.RC:
                assert after[address] == 0
            continue

        base = address - reg.offset
        decoded = bus.decode(address)
        assert decoded is not None
        allowed = {base + decoded.peripheral.register(name).offset for name in reg.affects}
        if reg.access in (Access.RW, Access.W1C):
            allowed.add(address)
        if decoded.peripheral is fabric.watchdog:
            allowed |= PWM_STATUS
        assert changed <= allowed, (site.id, changed - allowed)
        if reg.access is Access.RW:
            assert after[address] == value & reg.mask
        if reg.access is Access.W1C:
            assert after[address] == before[address] & ~value


hw_steps = st.one_of(
    st.tuples(st.just("tick"), st.integers(0, 50_000_000)),
    st.tuples(
        st.just("sense"),
        st.lists(st.integers(-(1 << 40), 1 << 40), min_size=4, max_size=4),
        st.lists(
            st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)),
            min_size=12,
            max_size=12,
        ),
        st.one_of(
            st.none(),
            st.builds(
                PositionFix,
                st.floats(),
                st.floats(),
                st.floats(),
                st.integers(0, 10),
                st.booleans(),
            ),
        ),
    ),
    st.tuples(st.just("access"), accesses),
)


@settings(max_examples=100, deadline=None)
@given(steps=st.lists(hw_steps, max_size=30))
def test_random_hardware_traffic_keeps_every_register_within_its_fields(
    steps: list[tuple[object, ...]],
) -> None:
    fabric = Fabric()
    for step in steps:
        match step:
            case ("tick", int(dt_ns)):
                fabric.tick(dt_ns)
            case ("sense", list(counts), list(echoes), fix):
                fabric.hw_apply_sense(counts, echoes, fix)  # type: ignore[arg-type]
            case ("access", ("read", int(address), _)):
                fabric.bus.read(address)
            case ("access", ("write", int(address), int(value))):
                fabric.bus.write(address, value)
        for address, stored in fabric.bus.snapshot().items():
            assert stored & ~SITE_BY_ADDRESS[address].register.mask == 0
        actuation = fabric.hw_read_actuation()
        assert all(-1.0 <= duty <= 1.0 for duty in actuation.duty)
        if actuation.watchdog_expired:
            assert actuation.duty == (0.0, 0.0, 0.0, 0.0)

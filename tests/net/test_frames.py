"""Radio frame codec: layout, round trip, every drop reason, replay handling, fuzzing."""

from __future__ import annotations

import dataclasses
import hmac
import re
import struct
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robot_firmware.net import frames
from robot_firmware.net.frames import (
    BODY_BYTES,
    BODY_STRUCT,
    FRAME_BYTES,
    FRAME_FORMAT,
    SWARM_KEY_ENV_VAR,
    DropReason,
    FrameDecoder,
    RadioFrame,
    Role,
    encode,
    frame_tag,
    initial_sequence,
    key_from_secret,
    next_sequence,
    parse_frame,
    sequence_is_newer,
    swarm_hash_from_name,
)

KEY = key_from_secret("test swarm secret")
OTHER_KEY = key_from_secret("another swarm secret")
SWARM_HASH = swarm_hash_from_name("alpha")
OWN_ID = 7
NOW_NS = 50_000_000_000
SECOND_NS = 1_000_000_000

# The body fields in BODY_FORMAT order, for crafting frames the encoder would refuse.
BODY_FIELDS = (
    "magic",
    "version",
    "role",
    "sender_id",
    "swarm_hash",
    "sequence",
    "timestamp_ns",
    "x_m",
    "y_m",
    "theta_rad",
    "xdot_mps",
    "ydot_mps",
    "thetadot_radps",
    "flags",
)


def make_frame(**overrides: Any) -> RadioFrame:
    fields: dict[str, Any] = {
        "role": Role.LEADER,
        "sender_id": 1,
        "swarm_hash": SWARM_HASH,
        "sequence": 100,
        "timestamp_ns": NOW_NS,
        "x_m": 1.25,
        "y_m": -0.5,
        "theta_rad": 1.5707963267948966,
        "xdot_mps": -0.35,
        "ydot_mps": 0.52,
        "thetadot_radps": 0.1,
        "localised": True,
    }
    fields.update(overrides)
    return RadioFrame(**fields)


def body_fields(frame: RadioFrame) -> dict[str, Any]:
    return {
        "magic": frames.MAGIC,
        "version": frames.VERSION,
        "role": int(frame.role),
        "sender_id": frame.sender_id,
        "swarm_hash": frame.swarm_hash,
        "sequence": frame.sequence,
        "timestamp_ns": frame.timestamp_ns,
        "x_m": frame.x_m,
        "y_m": frame.y_m,
        "theta_rad": frame.theta_rad,
        "xdot_mps": frame.xdot_mps,
        "ydot_mps": frame.ydot_mps,
        "thetadot_radps": frame.thetadot_radps,
        "flags": frame.flags,
    }


def craft(key: bytes = KEY, **overrides: Any) -> bytes:
    """A frame with raw body fields overwritten, signed with `key`."""
    fields = body_fields(make_frame()) | overrides
    body = BODY_STRUCT.pack(*(fields[name] for name in BODY_FIELDS))
    return body + frame_tag(body, key)


def new_decoder(**options: Any) -> FrameDecoder:
    settings_: dict[str, Any] = {"own_id": OWN_ID, "swarm_hash": SWARM_HASH} | options
    return FrameDecoder(KEY, **settings_)


def is_authentic(data: bytes) -> bool:
    return len(data) == FRAME_BYTES and hmac.compare_digest(
        data[BODY_BYTES:], frame_tag(data[:BODY_BYTES], KEY)
    )


# -- layout and round trip -----------------------------------------------------------


def test_documented_layout_table_matches_the_struct_formats() -> None:
    rows = re.findall(
        r"^\|\s*(\d+)\s*\|\s*(\d+)\s*\|\s*(\w+)\s*\|\s*(\w+)\s*\|", frames.__doc__ or "", re.M
    )
    assert rows, "the module docstring has no layout table"
    offset = 0
    formats = []
    for row_offset, row_bytes, row_format, _name in rows:
        assert int(row_offset) == offset
        assert int(row_bytes) == struct.calcsize("<" + row_format)
        offset += int(row_bytes)
        formats.append(row_format)
    assert offset == FRAME_BYTES == 88
    assert struct.calcsize("<" + "".join(formats)) == struct.calcsize(FRAME_FORMAT)
    names = {name for *_, name in rows}
    frame_fields = {f.name for f in dataclasses.fields(RadioFrame)} - {"localised"}
    assert names == frame_fields | {"magic", "version", "flags", "tag"}


@pytest.mark.parametrize(
    "frame",
    [
        make_frame(),
        make_frame(role=Role.FOLLOWER, localised=False, sender_id=0, swarm_hash=0),
        make_frame(sender_id=0xFFFF, sequence=0xFFFF_FFFF, timestamp_ns=NOW_NS + SECOND_NS),
        make_frame(x_m=-1.0e4, y_m=1.0e4, theta_rad=-10.0, thetadot_radps=100.0),
        make_frame(xdot_mps=60.0, ydot_mps=-80.0, x_m=-0.0, theta_rad=3.141592653589793),
    ],
)
def test_round_trip_preserves_every_field(frame: RadioFrame) -> None:
    data = encode(frame, KEY)
    assert len(data) == FRAME_BYTES == 88
    assert data[:2] == b"SW"
    assert data[2] == 1

    decoded = new_decoder(swarm_hash=frame.swarm_hash).decode(data, NOW_NS)

    assert decoded == frame
    for field in dataclasses.fields(RadioFrame):
        assert getattr(decoded, field.name) == getattr(frame, field.name)


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None, database=None)
@given(
    role=st.sampled_from(Role),
    sender_id=st.integers(0, 0xFFFF),
    swarm_hash=st.integers(0, 0xFFFF),
    sequence=st.integers(0, 0xFFFF_FFFF),
    timestamp_ns=st.integers(0, 2**64 - 1),
    pose=st.tuples(finite, finite, finite, finite, finite, finite),
    localised=st.booleans(),
)
def test_parse_inverts_encode_for_any_field_values(
    role: Role,
    sender_id: int,
    swarm_hash: int,
    sequence: int,
    timestamp_ns: int,
    pose: tuple[float, float, float, float, float, float],
    localised: bool,
) -> None:
    frame = RadioFrame(
        role=role,
        sender_id=sender_id,
        swarm_hash=swarm_hash,
        sequence=sequence,
        timestamp_ns=timestamp_ns,
        x_m=pose[0],
        y_m=pose[1],
        theta_rad=pose[2],
        xdot_mps=pose[3],
        ydot_mps=pose[4],
        thetadot_radps=pose[5],
        localised=localised,
    )
    data = encode(frame, KEY)
    assert len(data) == FRAME_BYTES
    parsed = parse_frame(data, KEY)
    expected = frames.content_problem(frame)
    assert parsed == (frame if expected is None else expected)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("sender_id", -1),
        ("sender_id", 0x1_0000),
        ("swarm_hash", 0x1_0000),
        ("sequence", 2**32),
        ("timestamp_ns", -1),
        ("timestamp_ns", 2**64),
        ("role", 2),
    ],
)
def test_frame_with_field_outside_its_wire_width_is_refused(field: str, value: int) -> None:
    with pytest.raises(ValueError):
        make_frame(**{field: value})


def test_short_or_empty_keys_are_refused() -> None:
    with pytest.raises(ValueError):
        encode(make_frame(), b"short")
    with pytest.raises(ValueError):
        FrameDecoder(b"")
    with pytest.raises(ValueError):
        key_from_secret("")


def test_key_from_secret_is_a_stable_32_byte_key_and_env_var_is_named() -> None:
    assert SWARM_KEY_ENV_VAR == "SWARM_KEY"
    assert key_from_secret("s3cret") == key_from_secret("s3cret")
    assert len(key_from_secret("s3cret")) == 32
    assert key_from_secret("s3cret") != key_from_secret("s3cret ")


# -- drop reasons --------------------------------------------------------------------

VALID = craft()
NOT_NEWER_PRELUDE = (craft(sequence=100),)


def _drop_cases() -> list[tuple[DropReason, tuple[bytes, ...], Any]]:
    """(reason, frames accepted first, the frame that must be dropped)."""
    return [
        (DropReason.NOT_BYTES, (), "not bytes at all"),
        (DropReason.TOO_SHORT, (), VALID[:-1]),
        (DropReason.TOO_SHORT, (), b""),
        (DropReason.TOO_LONG, (), VALID + b"\x00"),
        (DropReason.BAD_MAGIC, (), craft(magic=b"WS")),
        (DropReason.UNSUPPORTED_VERSION, (), craft(version=2)),
        (DropReason.UNSUPPORTED_VERSION, (), craft(version=0)),
        (DropReason.WRONG_SWARM, (), craft(swarm_hash=SWARM_HASH ^ 1)),
        (DropReason.BAD_TAG, (), craft(key=OTHER_KEY)),
        (DropReason.BAD_TAG, (), VALID[:-16] + bytes(16)),
        (DropReason.UNKNOWN_ROLE, (), craft(role=2)),
        (DropReason.UNKNOWN_ROLE, (), craft(role=255)),
        (DropReason.RESERVED_FLAGS, (), craft(flags=0b10)),
        (DropReason.RESERVED_FLAGS, (), craft(flags=0x8000_0001)),
        (DropReason.NON_FINITE, (), craft(x_m=float("nan"))),
        (DropReason.NON_FINITE, (), craft(theta_rad=float("inf"))),
        (DropReason.NON_FINITE, (), craft(thetadot_radps=float("-inf"))),
        (DropReason.OUT_OF_RANGE, (), craft(x_m=1.0e4 + 1.0)),
        (DropReason.OUT_OF_RANGE, (), craft(y_m=-2.0e4)),
        (DropReason.OUT_OF_RANGE, (), craft(theta_rad=10.01)),
        (DropReason.OUT_OF_RANGE, (), craft(xdot_mps=80.0, ydot_mps=80.0)),
        (DropReason.OUT_OF_RANGE, (), craft(ydot_mps=-101.0)),
        (DropReason.OUT_OF_RANGE, (), craft(thetadot_radps=-150.0)),
        (DropReason.OWN_FRAME, (), craft(sender_id=OWN_ID)),
        (DropReason.STALE, (), craft(timestamp_ns=NOW_NS - SECOND_NS - 1)),
        (DropReason.STALE, (), craft(timestamp_ns=0)),
        (DropReason.FROM_FUTURE, (), craft(timestamp_ns=NOW_NS + SECOND_NS + 1)),
        (DropReason.DUPLICATE, NOT_NEWER_PRELUDE, craft(sequence=100)),
        (DropReason.OUT_OF_ORDER, NOT_NEWER_PRELUDE, craft(sequence=99)),
        (DropReason.OUT_OF_ORDER, NOT_NEWER_PRELUDE, craft(sequence=100 + 2**31)),
    ]


DROP_CASES = _drop_cases()


def test_every_drop_reason_has_a_crafted_case() -> None:
    assert {reason for reason, _, _ in DROP_CASES} == set(DropReason)


@pytest.mark.parametrize(
    ("reason", "prelude", "bad"),
    DROP_CASES,
    ids=[f"{reason.value}-{i}" for i, (reason, _, _) in enumerate(DROP_CASES)],
)
def test_crafted_frame_is_dropped_and_counted_under_its_reason(
    reason: DropReason, prelude: tuple[bytes, ...], bad: Any
) -> None:
    decoder = new_decoder()
    for data in prelude:
        assert decoder.decode(data, NOW_NS) is not None

    assert decoder.decode(bad, NOW_NS) is None

    assert decoder.last_drop_reason is reason
    assert decoder.counters.dropped[reason] == 1
    assert decoder.counters.dropped_total == 1
    assert decoder.counters.accepted == len(prelude)
    assert decoder.counters.as_dict()[reason.value] == 1


@pytest.mark.parametrize(
    "data",
    [
        craft(x_m=1.0e4, y_m=-1.0e4, theta_rad=10.0, thetadot_radps=-100.0),
        craft(xdot_mps=60.0, ydot_mps=80.0),
        craft(timestamp_ns=NOW_NS - SECOND_NS),
        craft(timestamp_ns=NOW_NS + SECOND_NS),
        craft(sender_id=OWN_ID + 1),
    ],
)
def test_values_on_the_limits_are_accepted(data: bytes) -> None:
    decoder = new_decoder()
    assert decoder.decode(data, NOW_NS) is not None
    assert decoder.counters.accepted == 1
    assert decoder.last_drop_reason is None


def test_limits_are_configurable() -> None:
    decoder = new_decoder(own_id=None, swarm_hash=None, max_age_ns=10, max_future_ns=0)
    assert decoder.decode(craft(sender_id=OWN_ID, swarm_hash=123), NOW_NS) is not None
    assert decoder.decode(craft(sequence=101, timestamp_ns=NOW_NS - 11), NOW_NS) is None
    assert decoder.last_drop_reason is DropReason.STALE
    assert decoder.decode(craft(sequence=102, timestamp_ns=NOW_NS + 1), NOW_NS) is None
    assert decoder.last_drop_reason is DropReason.FROM_FUTURE


# -- authentication ------------------------------------------------------------------


def test_frame_signed_with_another_key_is_rejected() -> None:
    decoder = new_decoder()
    assert decoder.decode(encode(make_frame(), OTHER_KEY), NOW_NS) is None
    assert decoder.counters.dropped[DropReason.BAD_TAG] == 1
    assert decoder.decode(encode(make_frame(), KEY), NOW_NS) is not None


def test_single_flipped_bit_anywhere_is_rejected() -> None:
    decoder = new_decoder(swarm_hash=None)
    flips = 0
    for bit in range(FRAME_BYTES * 8):
        mutated = bytearray(VALID)
        mutated[bit // 8] ^= 1 << (bit % 8)
        assert decoder.decode(bytes(mutated), NOW_NS) is None, f"bit {bit} not detected"
        flips += 1
    assert decoder.counters.accepted == 0
    assert decoder.counters.total == flips == 704
    assert set(k for k, v in decoder.counters.dropped.items() if v) <= {
        DropReason.BAD_MAGIC,
        DropReason.UNSUPPORTED_VERSION,
        DropReason.BAD_TAG,
    }
    assert decoder.decode(VALID, NOW_NS) is not None


def test_bytes_like_inputs_are_decoded() -> None:
    decoder = new_decoder()
    assert decoder.decode(bytearray(craft(sequence=1)), NOW_NS) is not None
    assert decoder.decode(memoryview(craft(sequence=2)), NOW_NS) is not None


# -- sequence numbers and replay -----------------------------------------------------


def test_same_frame_twice_is_accepted_once() -> None:
    decoder = new_decoder()
    assert decoder.decode(VALID, NOW_NS) is not None
    assert decoder.decode(VALID, NOW_NS + 10_000_000) is None
    assert decoder.counters.accepted == 1
    assert decoder.counters.dropped[DropReason.DUPLICATE] == 1


def test_older_sequence_is_rejected_after_a_newer_one() -> None:
    decoder = new_decoder()
    assert decoder.decode(craft(sequence=5), NOW_NS) is not None
    assert decoder.decode(craft(sequence=7), NOW_NS) is not None
    assert decoder.decode(craft(sequence=6), NOW_NS) is None
    assert decoder.last_drop_reason is DropReason.OUT_OF_ORDER
    assert decoder.decode(craft(sequence=8), NOW_NS) is not None


def test_sequence_wrap_from_max_to_zero_is_accepted() -> None:
    decoder = new_decoder()
    assert decoder.decode(craft(sequence=0xFFFF_FFFF), NOW_NS) is not None
    assert decoder.decode(craft(sequence=0), NOW_NS) is not None
    assert decoder.decode(craft(sequence=1), NOW_NS) is not None
    assert decoder.decode(craft(sequence=0xFFFF_FFFF), NOW_NS) is None
    assert decoder.last_drop_reason is DropReason.OUT_OF_ORDER
    assert decoder.counters.accepted == 3


def test_serial_number_comparison_follows_rfc_1982() -> None:
    assert sequence_is_newer(1, 0)
    assert sequence_is_newer(0, 0xFFFF_FFFF)
    assert sequence_is_newer(0x7FFF_FFFF, 0)
    assert not sequence_is_newer(0x8000_0000, 0)  # undefined pair: not newer
    assert not sequence_is_newer(5, 5)
    assert not sequence_is_newer(0xFFFF_FFFF, 0)
    assert next_sequence(0xFFFF_FFFF) == 0
    assert next_sequence(41) == 42


def test_senders_have_independent_sequences() -> None:
    decoder = new_decoder()
    assert decoder.decode(craft(sender_id=1, sequence=500), NOW_NS) is not None
    assert decoder.decode(craft(sender_id=2, sequence=3), NOW_NS) is not None
    assert decoder.decode(craft(sender_id=1, sequence=3), NOW_NS) is None
    assert decoder.tracked_senders == 2


def test_rebooted_sender_is_heard_again_once_its_last_frame_has_aged_out() -> None:
    decoder = new_decoder()
    assert decoder.decode(craft(sequence=900, timestamp_ns=NOW_NS), NOW_NS) is not None
    later_ns = NOW_NS + SECOND_NS // 2
    assert decoder.decode(craft(sequence=0, timestamp_ns=later_ns), later_ns) is None
    much_later_ns = NOW_NS + 2 * SECOND_NS
    assert decoder.decode(craft(sequence=0, timestamp_ns=much_later_ns), much_later_ns) is not None
    assert decoder.decode(craft(sequence=0, timestamp_ns=much_later_ns), much_later_ns) is None


def test_replay_of_an_old_frame_after_the_sender_went_silent_is_stale() -> None:
    decoder = new_decoder()
    assert decoder.decode(VALID, NOW_NS) is not None
    assert decoder.decode(VALID, NOW_NS + 2 * SECOND_NS) is None
    assert decoder.last_drop_reason is DropReason.STALE


def test_rebooted_sender_starting_from_initial_sequence_is_heard_at_once() -> None:
    decoder = new_decoder()
    boot_ns = NOW_NS
    sequence = initial_sequence(boot_ns)
    for tick in range(10):  # 20 Hz broadcast, then a reboot 0.1 s later
        now_ns = boot_ns + tick * 50_000_000
        assert decoder.decode(craft(sequence=sequence, timestamp_ns=now_ns), now_ns) is not None
        sequence = next_sequence(sequence)
    reboot_ns = boot_ns + 10 * 50_000_000 + 100_000_000
    fresh = initial_sequence(reboot_ns)
    assert decoder.decode(craft(sequence=fresh, timestamp_ns=reboot_ns), reboot_ns) is not None


def test_sequence_state_is_bounded_by_the_sender_id_space() -> None:
    decoder = new_decoder(own_id=None)
    for sender_id in range(0, 0x1_0000, 257):
        decoder.decode(craft(sender_id=sender_id), NOW_NS)
    for sender_id in range(0, 0x1_0000, 257):
        decoder.decode(craft(sender_id=sender_id, sequence=101), NOW_NS)
    assert decoder.tracked_senders == len(range(0, 0x1_0000, 257))
    assert decoder.tracked_senders <= 0x1_0000


# -- fuzzing -------------------------------------------------------------------------

any_now_ns = st.one_of(
    st.just(NOW_NS),
    st.integers(-(2**70), 2**70),
)


def _assert_bookkeeping(decoder: FrameDecoder, fed: int, returned: int) -> None:
    counters = decoder.counters
    assert counters.total == fed
    assert counters.accepted == returned
    assert counters.dropped_total == fed - returned


@settings(max_examples=5000, deadline=None, database=None)
@given(
    data=st.one_of(
        st.binary(min_size=0, max_size=200),
        st.binary(min_size=FRAME_BYTES - 3, max_size=FRAME_BYTES - 3).map(
            lambda tail: b"SW\x01" + tail
        ),
    ),
    now_ns=any_now_ns,
)
def test_random_bytes_never_raise_and_are_all_counted(data: bytes, now_ns: int) -> None:
    decoder = new_decoder()
    result = decoder.decode(data, now_ns)
    assert result is None
    assert decoder.last_drop_reason is not None
    assert decoder.counters.dropped[decoder.last_drop_reason] == 1
    _assert_bookkeeping(decoder, fed=1, returned=0)


BODY_LAYOUT = [
    (name, fmt)
    for name, fmt in zip(
        BODY_FIELDS,
        ("2s", "B", "B", "H", "H", "I", "Q", "d", "d", "d", "d", "d", "d", "I"),
        strict=True,
    )
]

_wide_floats = st.one_of(
    st.floats(),
    st.sampled_from([1.0e4, -1.0e4, 1.0e4 + 1e-9, 10.0, 100.0, 100.1, -0.0, 1e308]),
)


def _field_values(name: str, fmt: str) -> st.SearchStrategy[Any]:
    if fmt == "2s":
        return st.one_of(st.just(b"SW"), st.binary(min_size=2, max_size=2))
    if fmt == "d":
        return _wide_floats
    bits = struct.calcsize("<" + fmt) * 8
    special = {
        "role": [0, 1, 2],
        "version": [1, 0, 2],
        "sender_id": [OWN_ID, 1, 2],
        "swarm_hash": [SWARM_HASH],
        "sequence": [99, 100, 101, 0, 0xFFFF_FFFF],
        "timestamp_ns": [NOW_NS, NOW_NS - SECOND_NS - 1, NOW_NS + SECOND_NS + 1],
        "flags": [0, 1, 2],
    }[name]
    return st.one_of(st.sampled_from(special), st.integers(0, 2**bits - 1))


@dataclasses.dataclass(frozen=True)
class Mutation:
    """One change to a frame's bytes; `resign` changes a body field and signs again."""

    kind: str
    position: int = 0
    payload: bytes = b""
    field: str = ""
    value: Any = None
    key: bytes = KEY

    def apply(self, data: bytes) -> bytes:
        if self.kind == "flip":
            if self.position // 8 >= len(data):
                return data
            mutated = bytearray(data)
            mutated[self.position // 8] ^= 1 << (self.position % 8)
            return bytes(mutated)
        if self.kind == "truncate":
            return data[: self.position]
        if self.kind == "extend":
            return data + self.payload
        if self.kind == "overwrite":
            end = self.position + len(self.payload)
            return (data[: self.position] + self.payload + data[end:])[:FRAME_BYTES]
        if len(data) < BODY_BYTES:
            return data
        fields = list(BODY_STRUCT.unpack(data[:BODY_BYTES]))
        fields[BODY_FIELDS.index(self.field)] = self.value
        body = BODY_STRUCT.pack(*fields)
        return body + frame_tag(body, self.key)


_resigns = [
    st.builds(
        Mutation,
        kind=st.just("resign"),
        field=st.just(name),
        value=_field_values(name, fmt),
        key=st.sampled_from([KEY, KEY, KEY, OTHER_KEY]),
    )
    for name, fmt in BODY_LAYOUT
]
mutations = st.one_of(
    st.builds(Mutation, kind=st.just("flip"), position=st.integers(0, FRAME_BYTES * 8 - 1)),
    st.builds(Mutation, kind=st.just("truncate"), position=st.integers(0, FRAME_BYTES - 1)),
    st.builds(Mutation, kind=st.just("extend"), payload=st.binary(min_size=1, max_size=40)),
    st.builds(
        Mutation,
        kind=st.just("overwrite"),
        position=st.integers(0, FRAME_BYTES - 1),
        payload=st.binary(min_size=1, max_size=16),
    ),
    *_resigns,
)


@settings(
    max_examples=5000,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    sequence=st.integers(0, 0xFFFF_FFFF),
    sender_id=st.sampled_from([1, 2, OWN_ID]),
    feed_original_first=st.booleans(),
    chain=st.lists(mutations, min_size=1, max_size=2),
    now_offset_ns=st.integers(-2 * SECOND_NS, 2 * SECOND_NS),
)
def test_mutated_frames_never_raise_and_every_drop_is_counted(
    sequence: int,
    sender_id: int,
    feed_original_first: bool,
    chain: list[Mutation],
    now_offset_ns: int,
) -> None:
    original = craft(sequence=sequence, sender_id=sender_id)
    mutated = original
    for mutation in chain:
        mutated = mutation.apply(mutated)
    fed_frames = [original, mutated] if feed_original_first else [mutated]

    decoder = new_decoder()
    now_ns = NOW_NS + now_offset_ns
    returned = 0
    for data in fed_frames:
        result = decoder.decode(data, now_ns)
        if result is None:
            assert decoder.last_drop_reason is not None
            continue
        returned += 1
        assert decoder.last_drop_reason is None
        assert is_authentic(data)
        assert encode(result, KEY) == data
    _assert_bookkeeping(decoder, fed=len(fed_frames), returned=returned)
    for data in fed_frames:
        if not is_authentic(data):
            assert parse_frame(data, KEY) in set(DropReason)

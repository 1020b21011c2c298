"""Radio frame codec: one robot's broadcast state as authenticated little-endian bytes.

A frame stands in for the lwIP UDP broadcast a robot sends to its peers (20 Hz). The
world's radio medium forwards it as opaque bytes; only robots encode and decode it.
Nothing here opens a socket, reads a clock or reads the environment: time comes in as
`now_ns` (simulation nanoseconds), the key and the run id as bytes from the caller.

Layout, version 3 (`FRAME_FORMAT`, little-endian, no padding, 100 bytes):

| offset | bytes | struct | field            | meaning                                        |
|-------:|------:|--------|------------------|------------------------------------------------|
|      0 |     2 | 2s     | magic            | b"SW"                                          |
|      2 |     1 | B      | version          | 3                                              |
|      3 |     1 | B      | role             | 0 follower, 1 acting leader                    |
|      4 |     2 | H      | sender_id        | robot index of the sender                      |
|      6 |     2 | H      | swarm_hash       | first two bytes of SHA-256 of the swarm name   |
|      8 |     8 | 8s     | run_id           | random id of the run the frame belongs to      |
|     16 |     4 | I      | sequence         | per-sender counter, wraps at 2**32             |
|     20 |     8 | Q      | timestamp_ns     | simulation time of the state, nanoseconds      |
|     28 |     8 | d      | x_m              | position x, metres                             |
|     36 |     8 | d      | y_m              | position y, metres                             |
|     44 |     8 | d      | theta_rad        | heading, radians                               |
|     52 |     8 | d      | xdot_mps         | velocity x, metres per second                  |
|     60 |     8 | d      | ydot_mps         | velocity y, metres per second                  |
|     68 |     8 | d      | thetadot_radps   | turn rate, radians per second                  |
|     76 |     4 | I      | flags            | bit 0 localised; bits 1..31 reserved, zero     |
|     80 |     4 | I      | term             | leader term the sender is in (DESIGN.md §7.1)  |
|     84 |    16 | 16s    | tag              | HMAC-SHA256 of bytes 0..83, first 16 bytes     |

`BODY_FORMAT` covers bytes 0..83 (the authenticated part); `FRAME_FORMAT` adds the tag.
Version 1 (88 bytes, no run id) and version 2 (96 bytes, no term) are no longer accepted.

Term: the leader term (epoch) the sender knows, authenticated with the rest of the body.
A frame whose role is leader is a claim to lead in that term; the highest term wins and ties
go to the lowest sender index (robot_firmware/leadership.py). The codec only carries it: any
value 0..2**32 - 1 is valid content.

Key: `derive_frame_key` turns the swarm's secret (32 random bytes made per run by `swarm up`,
read from the robot's credentials file, swarm_config/credentials.py) into the HMAC key with
HKDF-SHA256 (RFC 5869; `hkdf_sha256`), salt `KEY_SALT` and the swarm name as info, so two
swarms that share a secret still have different keys.

Run id: simulation time starts at 0 in every run, so a frame's time alone cannot tell a frame
recorded in an earlier run from a fresh one. Every run has a random `run_id` (in the
credentials file); it is authenticated with the rest of the body, and a decoder given one
drops frames of any other run.

Receiving: `FrameDecoder.decode` never raises. It returns the frame, or None and counts
the drop under one `DropReason` in `counters`. Checks run in this order and the first
failure names the reason:

1. input is bytes-like (`not_bytes`);
2. length is exactly `FRAME_BYTES` (`too_short`, `too_long`);
3. magic (`bad_magic`) and version (`unsupported_version`);
4. swarm hash, when the decoder was given one (`wrong_swarm`), then run id, when the decoder
   was given one (`wrong_run`). Both are checked before the tag so that another swarm's or
   another run's traffic (a replay of a recording) is told apart from forgeries;
5. authentication tag, compared in constant time (`bad_tag`). Nothing after this point
   looks at bytes that were not authenticated with the swarm key;
6. content: role value (`unknown_role`), reserved flag bits (`reserved_flags`), NaN or
   infinity in any float (`non_finite`), implausible pose or rate (`out_of_range`:
   |x|, |y| > 1e4 m, |theta| > 10 rad, planar speed > 100 m/s, |turn rate| > 100 rad/s);
7. the receiver's own frame echoed back (`own_frame`);
8. age: older than `max_age_ns` (`stale`) or ahead of `now_ns` by more than
   `max_future_ns` (`from_future`);
9. replay, against the sender's replay windows (below): the sequence equals the highest
   accepted in its window (`duplicate`) or is behind it (`out_of_order`), or it fits no
   window and its time is not later than every frame accepted from that sender
   (`out_of_order`).

Replay windows. One frame must not be able to lock a sender out: with a single "last
sequence" per sender, one authentic frame with a sequence far ahead (a replay across a
reboot, or an insider) made every later frame of the real sender "old". So each sender has
up to `MAX_WINDOWS_PER_SENDER` windows, each the highest sequence accepted in it and the
latest time accepted in it. A frame belongs to a window when its sequence is at most
`REPLAY_WINDOW` behind that window's highest or at most `MAX_SEQUENCE_JUMP` ahead (RFC 1982
serial arithmetic over 32 bits); it is judged there only. A frame that belongs to no window
opens a new one, but only when its time is later than every frame accepted from the sender so
far: a replayed old frame never does, a rebooted sender (any fresh sequence, current time)
does at once, and the real sender's stream keeps its own window whatever sequence a forged
frame carried. With all windows in use the one heard from longest ago is forgotten; a window
whose latest frame is older than `max_age_ns` is forgotten too (any replay into it would be
stale). A sender that starts from `initial_sequence(now_ns)` after a reboot usually stays in
its old window and is heard at once either way.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import math
import operator
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

MAGIC = b"SW"
VERSION = 3

BODY_FORMAT = "<2sBBHH8sIQ6dII"
"""Authenticated part: magic, version, role, sender, swarm, run, sequence, time, pose, rate,
flags, term."""
TAG_BYTES = 16
FRAME_FORMAT = f"{BODY_FORMAT}{TAG_BYTES}s"
"""Whole frame: `BODY_FORMAT` followed by the truncated HMAC-SHA256 tag."""

BODY_STRUCT = struct.Struct(BODY_FORMAT)
FRAME_STRUCT = struct.Struct(FRAME_FORMAT)
BODY_BYTES = BODY_STRUCT.size
FRAME_BYTES = FRAME_STRUCT.size

RUN_ID_BYTES = 8
NO_RUN_ID = bytes(RUN_ID_BYTES)
"""The run id of frames made outside a networked run (in-process simulation, tests)."""

MIN_KEY_BYTES = 16
"""Shortest key accepted; `derive_frame_key` gives 32."""
MIN_SECRET_BYTES = 16
"""Shortest secret `derive_frame_key` accepts (a run's secret has 32 random bytes)."""
KEY_BYTES = 32
KEY_SALT = b"swarm-cps radio frame key v2"
"""HKDF salt of the frame key: the purpose, so the secret yields no other key by accident."""

FLAG_LOCALISED = 1 << 0
RESERVED_FLAGS_MASK = 0xFFFF_FFFF & ~FLAG_LOCALISED

SEQUENCE_MODULUS = 1 << 32
_SEQUENCE_HALF = 1 << 31
U16_MAX = 0xFFFF
U32_MAX = 0xFFFF_FFFF
U64_MAX = 0xFFFF_FFFF_FFFF_FFFF

MAX_ABS_POSITION_M = 1.0e4
MAX_ABS_HEADING_RAD = 10.0
MAX_SPEED_MPS = 100.0
MAX_ABS_TURN_RATE_RADPS = 100.0

DEFAULT_MAX_AGE_NS = 1_000_000_000
DEFAULT_MAX_FUTURE_NS = 1_000_000_000

REPLAY_WINDOW = 64
"""Sequences behind a window's highest that still belong to it (dropped as out of order)."""
MAX_SEQUENCE_JUMP = 1024
"""Sequences ahead of a window's highest that still belong to it (lost frames in between)."""
MAX_WINDOWS_PER_SENDER = 4

_INT_FIELDS: tuple[tuple[str, int], ...] = (
    ("sender_id", U16_MAX),
    ("swarm_hash", U16_MAX),
    ("sequence", U32_MAX),
    ("timestamp_ns", U64_MAX),
    ("term", U32_MAX),
)
_FLOAT_FIELDS = ("x_m", "y_m", "theta_rad", "xdot_mps", "ydot_mps", "thetadot_radps")


class Role(enum.IntEnum):
    """What the sender does in the formation."""

    FOLLOWER = 0
    LEADER = 1


_ROLES: dict[int, Role] = {int(role): role for role in Role}


class DropReason(enum.Enum):
    """Why a received frame was dropped, in the order the checks run."""

    NOT_BYTES = "not_bytes"
    TOO_SHORT = "too_short"
    TOO_LONG = "too_long"
    BAD_MAGIC = "bad_magic"
    UNSUPPORTED_VERSION = "unsupported_version"
    WRONG_SWARM = "wrong_swarm"
    WRONG_RUN = "wrong_run"
    BAD_TAG = "bad_tag"
    UNKNOWN_ROLE = "unknown_role"
    RESERVED_FLAGS = "reserved_flags"
    NON_FINITE = "non_finite"
    OUT_OF_RANGE = "out_of_range"
    OWN_FRAME = "own_frame"
    STALE = "stale"
    FROM_FUTURE = "from_future"
    DUPLICATE = "duplicate"
    OUT_OF_ORDER = "out_of_order"


@dataclass(frozen=True, slots=True, kw_only=True)
class RadioFrame:
    """One robot's broadcast state.

    Integer fields are checked against their wire width on construction (ValueError);
    floats are stored as given, so a sender can build a frame with a NaN and see the
    receivers drop it. `content_problem` tells whether receivers will accept the content.
    """

    role: Role
    sender_id: int
    sequence: int
    timestamp_ns: int
    x_m: float
    y_m: float
    theta_rad: float
    xdot_mps: float
    ydot_mps: float
    thetadot_radps: float
    localised: bool
    swarm_hash: int = 0
    run_id: bytes = NO_RUN_ID
    term: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "role", Role(self.role))
        for name, limit in _INT_FIELDS:
            value = operator.index(getattr(self, name))
            if not 0 <= value <= limit:
                raise ValueError(f"{name}={value} is outside 0..{limit}")
            object.__setattr__(self, name, value)
        for name in _FLOAT_FIELDS:
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "localised", bool(self.localised))
        object.__setattr__(self, "run_id", _check_run_id(self.run_id))

    @property
    def flags(self) -> int:
        """The flags word as sent."""
        return FLAG_LOCALISED if self.localised else 0

    @classmethod
    def _from_wire(cls, values: tuple[object, ...]) -> RadioFrame:
        """A frame from fields in `__slots__` order that the wire format already bounds (the
        struct's widths, a known role, floats, the run id's length): the checks of
        `__post_init__` cannot fail on them, so a receiver skips them."""
        frame = object.__new__(cls)
        for set_slot, value in zip(_SLOT_SETTERS, values, strict=True):
            set_slot(frame, value)
        return frame


_SLOT_SETTERS: tuple[Callable[[RadioFrame, object], None], ...] = tuple(
    getattr(RadioFrame, name).__set__ for name in RadioFrame.__slots__
)
"""Each slot's own setter, in `__slots__` order: what `object.__setattr__` finds by name."""


def hkdf_sha256(ikm: bytes, salt: bytes, info: bytes, length: int) -> bytes:
    """HKDF (RFC 5869) with SHA-256: extract a pseudorandom key from `ikm` and `salt`, then
    expand it to `length` bytes bound to `info`."""
    hash_bytes = hashlib.sha256().digest_size
    if not 0 < length <= 255 * hash_bytes:
        raise ValueError(f"HKDF-SHA256 gives 1..{255 * hash_bytes} bytes, not {length}")
    prk = hmac.digest(salt or bytes(hash_bytes), ikm, "sha256")
    okm = b""
    block = b""
    counter = 1
    while len(okm) < length:
        block = hmac.digest(prk, block + info + bytes([counter]), "sha256")
        okm += block
        counter += 1
    return okm[:length]


def derive_frame_key(secret: bytes, swarm_name: str) -> bytes:
    """The 32-byte HMAC key of a swarm's frames: HKDF-SHA256 of its secret, `KEY_SALT` as
    salt and the swarm name as info."""
    if not isinstance(secret, bytes | bytearray) or len(secret) < MIN_SECRET_BYTES:
        raise ValueError(f"the swarm secret must be at least {MIN_SECRET_BYTES} bytes")
    if not swarm_name:
        raise ValueError("the swarm name is empty")
    return hkdf_sha256(bytes(secret), KEY_SALT, swarm_name.encode("utf-8"), KEY_BYTES)


def key_from_secret(secret: str, swarm_name: str = "lab") -> bytes:
    """The frame key for a text secret (tests, benches, in-process runs): `derive_frame_key`
    of its UTF-8 bytes, padded by SHA-256 to the minimum length. Networked runs use the
    random secret of their credentials file instead."""
    if not secret:
        raise ValueError("the swarm secret is empty")
    return derive_frame_key(hashlib.sha256(secret.encode("utf-8")).digest(), swarm_name)


def swarm_hash_from_name(swarm_name: str) -> int:
    """The 16-bit swarm hash carried in every frame: first two bytes of SHA-256, little-endian."""
    return int.from_bytes(hashlib.sha256(swarm_name.encode("utf-8")).digest()[:2], "little")


def frame_tag(body: bytes, key: bytes) -> bytes:
    """Authentication tag of a frame body: HMAC-SHA256 under `key`, first `TAG_BYTES` bytes."""
    return hmac.digest(key, body, "sha256")[:TAG_BYTES]


def sequence_distance(candidate: int, reference: int) -> int:
    """How far `candidate` is ahead of `reference` (negative: behind) in 32-bit serial
    number arithmetic (RFC 1982), in -2**31 ..  2**31 - 1."""
    distance = (candidate - reference) % SEQUENCE_MODULUS
    return distance - SEQUENCE_MODULUS if distance >= _SEQUENCE_HALF else distance


def sequence_is_newer(candidate: int, reference: int) -> bool:
    """True when `candidate` follows `reference` in 32-bit serial number arithmetic (RFC 1982).

    The pair exactly half the sequence space apart is undefined there; it counts as not newer.
    """
    distance = (candidate - reference) % SEQUENCE_MODULUS
    return 0 < distance < _SEQUENCE_HALF


def next_sequence(sequence: int) -> int:
    """The sequence number after `sequence`, wrapping from 2**32 - 1 to 0."""
    return (sequence + 1) % SEQUENCE_MODULUS


def initial_sequence(now_ns: int) -> int:
    """A first sequence number for a sender that boots at `now_ns`: simulation milliseconds.

    Sending at most one frame per millisecond, a rebooted sender starts ahead of where it
    stopped (for up to 2**31 ms, about 24 days).
    """
    return (now_ns // 1_000_000) % SEQUENCE_MODULUS


def encode(frame: RadioFrame, key: bytes) -> bytes:
    """The `FRAME_BYTES` bytes of `frame`, signed with the swarm `key`."""
    _check_key(key)
    body = BODY_STRUCT.pack(
        MAGIC,
        VERSION,
        int(frame.role),
        frame.sender_id,
        frame.swarm_hash,
        frame.run_id,
        frame.sequence,
        frame.timestamp_ns,
        frame.x_m,
        frame.y_m,
        frame.theta_rad,
        frame.xdot_mps,
        frame.ydot_mps,
        frame.thetadot_radps,
        frame.flags,
        frame.term,
    )
    return body + frame_tag(body, key)


def content_problem(frame: RadioFrame) -> DropReason | None:
    """The reason receivers would drop `frame` for its pose or rate values, or None."""
    values = (
        frame.x_m,
        frame.y_m,
        frame.theta_rad,
        frame.xdot_mps,
        frame.ydot_mps,
        frame.thetadot_radps,
    )
    isfinite = math.isfinite
    if not (
        isfinite(values[0])
        and isfinite(values[1])
        and isfinite(values[2])
        and isfinite(values[3])
        and isfinite(values[4])
        and isfinite(values[5])
    ):
        return DropReason.NON_FINITE
    if (
        abs(frame.x_m) > MAX_ABS_POSITION_M
        or abs(frame.y_m) > MAX_ABS_POSITION_M
        or abs(frame.theta_rad) > MAX_ABS_HEADING_RAD
        or math.hypot(frame.xdot_mps, frame.ydot_mps) > MAX_SPEED_MPS
        or abs(frame.thetadot_radps) > MAX_ABS_TURN_RATE_RADPS
    ):
        return DropReason.OUT_OF_RANGE
    return None


def parse_frame(
    data: bytes | bytearray | memoryview,
    key: bytes,
    *,
    swarm_hash: int | None = None,
    run_id: bytes | None = None,
) -> RadioFrame | DropReason:
    """Checks 1 to 6 of the module docstring, with no per-sender state; never raises on `data`.

    Returns the frame, or the reason it would be dropped. With `swarm_hash` (`run_id`) None
    that field is not checked.
    """
    _check_key(key)
    return _parse(data, key, swarm_hash, None if run_id is None else _check_run_id(run_id))


_DROP_REASON_VALUES = {reason: reason.value for reason in DropReason}
"""Each reason's value, looked up once (an enum's `.value` is a descriptor call)."""


@dataclass(slots=True)
class FrameCounters:
    """Frames seen by one decoder: accepted, and dropped per reason (every reason present)."""

    accepted: int = 0
    dropped: dict[DropReason, int] = field(default_factory=lambda: dict.fromkeys(DropReason, 0))

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())

    @property
    def total(self) -> int:
        """Every frame fed to the decoder."""
        return self.accepted + self.dropped_total

    def as_dict(self) -> dict[str, int]:
        """Flat counters for telemetry: `accepted` and one entry per drop reason value."""
        values = _DROP_REASON_VALUES
        return {"accepted": self.accepted} | {
            values[reason]: count for reason, count in self.dropped.items()
        }


@dataclass(slots=True)
class ReplayWindow:
    """One stream of a sender's frames: the highest sequence and latest time accepted in it."""

    highest_sequence: int
    latest_ns: int

    def offset(self, sequence: int) -> int | None:
        """How far `sequence` is ahead of the highest (<= 0: behind), or None when it does not
        belong to this window."""
        distance = sequence_distance(sequence, self.highest_sequence)
        return distance if -REPLAY_WINDOW < distance <= MAX_SEQUENCE_JUMP else None


@dataclass(slots=True)
class SenderWindows:
    """A sender's replay windows, most recently used first, and its latest accepted time."""

    windows: list[ReplayWindow]
    latest_ns: int


class FrameDecoder:
    """Checks and decodes the frames one robot receives, keeping each sender's replay windows.

    State is at most `MAX_WINDOWS_PER_SENDER` windows per sender id (u16), so bounded by
    65,536 senders.
    """

    def __init__(
        self,
        key: bytes,
        *,
        own_id: int | None = None,
        swarm_hash: int | None = None,
        run_id: bytes | None = None,
        max_age_ns: int = DEFAULT_MAX_AGE_NS,
        max_future_ns: int = DEFAULT_MAX_FUTURE_NS,
    ) -> None:
        _check_key(key)
        if max_age_ns < 0 or max_future_ns < 0:
            raise ValueError("max_age_ns and max_future_ns must not be negative")
        for name, value in (("own_id", own_id), ("swarm_hash", swarm_hash)):
            if value is not None and not 0 <= value <= U16_MAX:
                raise ValueError(f"{name}={value} is outside 0..{U16_MAX}")
        self._key = bytes(key)
        self.own_id = own_id
        self.swarm_hash = swarm_hash
        self.run_id = None if run_id is None else _check_run_id(run_id)
        self.max_age_ns = max_age_ns
        self.max_future_ns = max_future_ns
        self.counters = FrameCounters()
        self.last_drop_reason: DropReason | None = None
        self._senders: dict[int, SenderWindows] = {}

    @property
    def tracked_senders(self) -> int:
        """Senders with at least one replay window."""
        return len(self._senders)

    def windows_of(self, sender_id: int) -> int:
        """How many replay windows `sender_id` has."""
        sender = self._senders.get(sender_id)
        return 0 if sender is None else len(sender.windows)

    def decode(self, data: bytes | bytearray | memoryview, now_ns: int) -> RadioFrame | None:
        """The frame in `data` if it passes every check at time `now_ns`, else None (counted)."""
        outcome = self._judge(data, now_ns)
        if isinstance(outcome, DropReason):
            self.counters.dropped[outcome] += 1
            self.last_drop_reason = outcome
            return None
        self.counters.accepted += 1
        self.last_drop_reason = None
        return outcome

    def _judge(self, data: object, now_ns: int) -> RadioFrame | DropReason:
        parsed = _parse(data, self._key, self.swarm_hash, self.run_id)
        if isinstance(parsed, DropReason):
            return parsed
        if parsed.sender_id == self.own_id:
            return DropReason.OWN_FRAME
        if parsed.timestamp_ns < now_ns - self.max_age_ns:
            return DropReason.STALE
        if parsed.timestamp_ns > now_ns + self.max_future_ns:
            return DropReason.FROM_FUTURE
        problem = self._replay_check(parsed, now_ns)
        return parsed if problem is None else problem

    def _replay_check(self, frame: RadioFrame, now_ns: int) -> DropReason | None:
        """Judge `frame` against its sender's windows and, when accepted, record it."""
        sender = self._senders.get(frame.sender_id)
        if sender is not None:
            sender.windows = [w for w in sender.windows if w.latest_ns >= now_ns - self.max_age_ns]
            if not sender.windows:
                del self._senders[frame.sender_id]
                sender = None
        if sender is None:
            window = ReplayWindow(frame.sequence, frame.timestamp_ns)
            self._senders[frame.sender_id] = SenderWindows([window], frame.timestamp_ns)
            return None
        for index, window in enumerate(sender.windows):
            offset = window.offset(frame.sequence)
            if offset is None:
                continue
            if offset == 0:
                return DropReason.DUPLICATE
            if offset < 0:
                return DropReason.OUT_OF_ORDER
            window.highest_sequence = frame.sequence
            window.latest_ns = max(window.latest_ns, frame.timestamp_ns)
            sender.windows.insert(0, sender.windows.pop(index))
            sender.latest_ns = max(sender.latest_ns, frame.timestamp_ns)
            return None
        if frame.timestamp_ns <= sender.latest_ns:
            return DropReason.OUT_OF_ORDER
        sender.windows.insert(0, ReplayWindow(frame.sequence, frame.timestamp_ns))
        if len(sender.windows) > MAX_WINDOWS_PER_SENDER:
            oldest = min(range(len(sender.windows)), key=lambda i: sender.windows[i].latest_ns)
            del sender.windows[oldest]
        sender.latest_ns = frame.timestamp_ns
        return None


_SENDER_ID = struct.Struct("<H")
_SENDER_ID_OFFSET = 4


def claimed_sender(data: bytes) -> int | None:
    """The sender id a frame claims, read without the key (None when it is too short to say).

    For the radio medium, which knows which robot transmitted (only robotN may put on
    `radio/tx/robotN`) and drops a frame that claims another sender: every robot holds the
    swarm key, so the tag alone cannot tell one robot from another.
    """
    if len(data) < _SENDER_ID_OFFSET + _SENDER_ID.size:
        return None
    return int(_SENDER_ID.unpack_from(data, _SENDER_ID_OFFSET)[0])


def _check_key(key: bytes) -> None:
    if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
        raise ValueError(f"the swarm key must be at least {MIN_KEY_BYTES} bytes")


def _check_run_id(run_id: bytes) -> bytes:
    if not isinstance(run_id, bytes | bytearray) or len(run_id) != RUN_ID_BYTES:
        raise ValueError(f"the run id must be {RUN_ID_BYTES} bytes")
    return bytes(run_id)


def _parse(
    data: object, key: bytes, swarm_hash: int | None, run_id: bytes | None
) -> RadioFrame | DropReason:
    if not isinstance(data, bytes | bytearray | memoryview):
        return DropReason.NOT_BYTES
    try:
        raw = bytes(data)
    except (TypeError, ValueError):  # e.g. a released memoryview
        return DropReason.NOT_BYTES
    if len(raw) < FRAME_BYTES:
        return DropReason.TOO_SHORT
    if len(raw) > FRAME_BYTES:
        return DropReason.TOO_LONG
    # motion: x_m, y_m, theta_rad, xdot_mps, ydot_mps, thetadot_radps, in `RadioFrame`'s order.
    (
        magic,
        version,
        role,
        sender_id,
        frame_swarm_hash,
        frame_run_id,
        sequence,
        timestamp_ns,
        *motion,
        flags,
        term,
        tag,
    ) = FRAME_STRUCT.unpack(raw)
    if magic != MAGIC:
        return DropReason.BAD_MAGIC
    if version != VERSION:
        return DropReason.UNSUPPORTED_VERSION
    if swarm_hash is not None and frame_swarm_hash != swarm_hash:
        return DropReason.WRONG_SWARM
    if run_id is not None and frame_run_id != run_id:
        return DropReason.WRONG_RUN
    if not hmac.compare_digest(frame_tag(raw[:BODY_BYTES], key), tag):
        return DropReason.BAD_TAG
    known_role = _ROLES.get(role)
    if known_role is None:
        return DropReason.UNKNOWN_ROLE
    if flags & RESERVED_FLAGS_MASK:
        return DropReason.RESERVED_FLAGS
    frame = RadioFrame._from_wire(
        (known_role, sender_id, sequence, timestamp_ns, *motion)
        + (bool(flags & FLAG_LOCALISED), frame_swarm_hash, frame_run_id, term)
    )
    problem = content_problem(frame)
    return frame if problem is None else problem

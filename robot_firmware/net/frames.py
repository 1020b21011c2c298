"""Radio frame codec: one robot's broadcast state as authenticated little-endian bytes.

A frame stands in for the lwIP UDP broadcast a robot sends to its peers (20 Hz). The
world's radio medium forwards it as opaque bytes; only robots encode and decode it.
Nothing here opens a socket, reads a clock or reads the environment: time comes in as
`now_ns` (simulation nanoseconds) and the swarm key as bytes from the caller.

Layout, version 1 (`FRAME_FORMAT`, little-endian, no padding, 88 bytes):

| offset | bytes | struct | field            | meaning                                        |
|-------:|------:|--------|------------------|------------------------------------------------|
|      0 |     2 | 2s     | magic            | b"SW"                                          |
|      2 |     1 | B      | version          | 1                                              |
|      3 |     1 | B      | role             | 0 follower, 1 leader                           |
|      4 |     2 | H      | sender_id        | robot index of the sender                      |
|      6 |     2 | H      | swarm_hash       | first two bytes of SHA-256 of the swarm name   |
|      8 |     4 | I      | sequence         | per-sender counter, wraps at 2**32             |
|     12 |     8 | Q      | timestamp_ns     | simulation time of the state, nanoseconds      |
|     20 |     8 | d      | x_m              | position x, metres                             |
|     28 |     8 | d      | y_m              | position y, metres                             |
|     36 |     8 | d      | theta_rad        | heading, radians                               |
|     44 |     8 | d      | xdot_mps         | velocity x, metres per second                  |
|     52 |     8 | d      | ydot_mps         | velocity y, metres per second                  |
|     60 |     8 | d      | thetadot_radps   | turn rate, radians per second                  |
|     68 |     4 | I      | flags            | bit 0 localised; bits 1..31 reserved, zero     |
|     72 |    16 | 16s    | tag              | HMAC-SHA256 of bytes 0..71, first 16 bytes     |

`BODY_FORMAT` covers bytes 0..71 (the authenticated part); `FRAME_FORMAT` adds the tag.

Receiving: `FrameDecoder.decode` never raises. It returns the frame, or None and counts
the drop under one `DropReason` in `counters`. Checks run in this order and the first
failure names the reason:

1. input is bytes-like (`not_bytes`);
2. length is exactly `FRAME_BYTES` (`too_short`, `too_long`);
3. magic (`bad_magic`) and version (`unsupported_version`);
4. swarm hash, when the decoder was given one (`wrong_swarm`). This is checked before the
   tag so that another swarm's traffic on a shared medium is told apart from forgeries;
5. authentication tag, compared in constant time (`bad_tag`). Nothing after this point
   looks at bytes that were not authenticated with the swarm key;
6. content: role value (`unknown_role`), reserved flag bits (`reserved_flags`), NaN or
   infinity in any float (`non_finite`), implausible pose or rate (`out_of_range`:
   |x|, |y| > 1e4 m, |theta| > 10 rad, planar speed > 100 m/s, |turn rate| > 100 rad/s);
7. the receiver's own frame echoed back (`own_frame`);
8. age: older than `max_age_ns` (`stale`) or ahead of `now_ns` by more than
   `max_future_ns` (`from_future`);
9. sequence against the last frame accepted from the same sender, in RFC 1982 serial
   number arithmetic over 32 bits: equal (`duplicate`) or not newer (`out_of_order`).
   A sender's entry is forgotten once its last accepted frame is older than
   `max_age_ns`; any replay of an earlier frame is then stale anyway, and a sender
   that rebooted with a fresh sequence is heard again. A sender that wants to be
   heard at once after a reboot starts from `initial_sequence(now_ns)`.

The key is per swarm. Firmware reads the secret from the environment variable named by
`SWARM_KEY_ENV_VAR` and turns it into a key with `key_from_secret`; this module only
names the variable.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import math
import operator
import struct
from dataclasses import dataclass, field

SWARM_KEY_ENV_VAR = "SWARM_KEY"
"""Name of the environment variable holding the swarm's shared secret (read by the firmware)."""

MAGIC = b"SW"
VERSION = 1

BODY_FORMAT = "<2sBBHHIQ6dI"
"""Authenticated part: magic, version, role, sender, swarm, sequence, time, pose, rate, flags."""
TAG_BYTES = 16
FRAME_FORMAT = f"{BODY_FORMAT}{TAG_BYTES}s"
"""Whole frame: `BODY_FORMAT` followed by the truncated HMAC-SHA256 tag."""

BODY_STRUCT = struct.Struct(BODY_FORMAT)
FRAME_STRUCT = struct.Struct(FRAME_FORMAT)
BODY_BYTES = BODY_STRUCT.size
FRAME_BYTES = FRAME_STRUCT.size

MIN_KEY_BYTES = 16
"""Shortest key accepted; `key_from_secret` gives 32."""

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

_INT_FIELDS: tuple[tuple[str, int], ...] = (
    ("sender_id", U16_MAX),
    ("swarm_hash", U16_MAX),
    ("sequence", U32_MAX),
    ("timestamp_ns", U64_MAX),
)
_FLOAT_FIELDS = ("x_m", "y_m", "theta_rad", "xdot_mps", "ydot_mps", "thetadot_radps")


class Role(enum.IntEnum):
    """What the sender does in the formation."""

    FOLLOWER = 0
    LEADER = 1


_ROLE_VALUES = frozenset(int(role) for role in Role)


class DropReason(enum.Enum):
    """Why a received frame was dropped, in the order the checks run."""

    NOT_BYTES = "not_bytes"
    TOO_SHORT = "too_short"
    TOO_LONG = "too_long"
    BAD_MAGIC = "bad_magic"
    UNSUPPORTED_VERSION = "unsupported_version"
    WRONG_SWARM = "wrong_swarm"
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

    @property
    def flags(self) -> int:
        """The flags word as sent."""
        return FLAG_LOCALISED if self.localised else 0


def key_from_secret(secret: str) -> bytes:
    """The 32-byte swarm key for a shared secret: SHA-256 of its UTF-8 encoding."""
    if not secret:
        raise ValueError("the swarm secret is empty")
    return hashlib.sha256(secret.encode("utf-8")).digest()


def swarm_hash_from_name(swarm_name: str) -> int:
    """The 16-bit swarm hash carried in every frame: first two bytes of SHA-256, little-endian."""
    return int.from_bytes(hashlib.sha256(swarm_name.encode("utf-8")).digest()[:2], "little")


def frame_tag(body: bytes, key: bytes) -> bytes:
    """Authentication tag of a frame body: HMAC-SHA256 under `key`, first `TAG_BYTES` bytes."""
    return hmac.digest(key, body, "sha256")[:TAG_BYTES]


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
    stopped (for up to 2**31 ms, about 24 days), so receivers accept it at once.
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
        frame.sequence,
        frame.timestamp_ns,
        frame.x_m,
        frame.y_m,
        frame.theta_rad,
        frame.xdot_mps,
        frame.ydot_mps,
        frame.thetadot_radps,
        frame.flags,
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
    if not all(math.isfinite(value) for value in values):
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
    data: bytes | bytearray | memoryview, key: bytes, *, swarm_hash: int | None = None
) -> RadioFrame | DropReason:
    """Checks 1 to 6 of the module docstring, with no per-sender state; never raises on `data`.

    Returns the frame, or the reason it would be dropped. With `swarm_hash` None the
    swarm hash field is not checked.
    """
    _check_key(key)
    return _parse(data, key, swarm_hash)


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
        return {"accepted": self.accepted} | {
            reason.value: count for reason, count in self.dropped.items()
        }


class FrameDecoder:
    """Checks and decodes the frames one robot receives, remembering each sender's sequence.

    Sequence state is one entry per sender id (u16), so at most 65,536 entries.
    """

    def __init__(
        self,
        key: bytes,
        *,
        own_id: int | None = None,
        swarm_hash: int | None = None,
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
        self.max_age_ns = max_age_ns
        self.max_future_ns = max_future_ns
        self.counters = FrameCounters()
        self.last_drop_reason: DropReason | None = None
        # sender id -> (sequence, timestamp_ns) of the last frame accepted from it
        self._last_accepted: dict[int, tuple[int, int]] = {}

    @property
    def tracked_senders(self) -> int:
        """Senders whose last sequence number is remembered."""
        return len(self._last_accepted)

    def decode(self, data: bytes | bytearray | memoryview, now_ns: int) -> RadioFrame | None:
        """The frame in `data` if it passes every check at time `now_ns`, else None (counted)."""
        outcome = self._judge(data, now_ns)
        if isinstance(outcome, DropReason):
            self.counters.dropped[outcome] += 1
            self.last_drop_reason = outcome
            return None
        self._last_accepted[outcome.sender_id] = (outcome.sequence, outcome.timestamp_ns)
        self.counters.accepted += 1
        self.last_drop_reason = None
        return outcome

    def _judge(self, data: object, now_ns: int) -> RadioFrame | DropReason:
        parsed = _parse(data, self._key, self.swarm_hash)
        if isinstance(parsed, DropReason):
            return parsed
        if parsed.sender_id == self.own_id:
            return DropReason.OWN_FRAME
        if parsed.timestamp_ns < now_ns - self.max_age_ns:
            return DropReason.STALE
        if parsed.timestamp_ns > now_ns + self.max_future_ns:
            return DropReason.FROM_FUTURE
        last = self._last_accepted.get(parsed.sender_id)
        if last is None:
            return parsed
        last_sequence, last_timestamp_ns = last
        if last_timestamp_ns < now_ns - self.max_age_ns:
            del self._last_accepted[parsed.sender_id]
            return parsed
        if parsed.sequence == last_sequence:
            return DropReason.DUPLICATE
        if not sequence_is_newer(parsed.sequence, last_sequence):
            return DropReason.OUT_OF_ORDER
        return parsed


def _check_key(key: bytes) -> None:
    if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
        raise ValueError(f"the swarm key must be at least {MIN_KEY_BYTES} bytes")


def _parse(data: object, key: bytes, swarm_hash: int | None) -> RadioFrame | DropReason:
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
    (
        magic,
        version,
        role,
        sender_id,
        frame_swarm_hash,
        sequence,
        timestamp_ns,
        x_m,
        y_m,
        theta_rad,
        xdot_mps,
        ydot_mps,
        thetadot_radps,
        flags,
        tag,
    ) = FRAME_STRUCT.unpack(raw)
    if magic != MAGIC:
        return DropReason.BAD_MAGIC
    if version != VERSION:
        return DropReason.UNSUPPORTED_VERSION
    if swarm_hash is not None and frame_swarm_hash != swarm_hash:
        return DropReason.WRONG_SWARM
    if not hmac.compare_digest(frame_tag(raw[:BODY_BYTES], key), tag):
        return DropReason.BAD_TAG
    if role not in _ROLE_VALUES:
        return DropReason.UNKNOWN_ROLE
    if flags & RESERVED_FLAGS_MASK:
        return DropReason.RESERVED_FLAGS
    frame = RadioFrame(
        role=Role(role),
        sender_id=sender_id,
        swarm_hash=frame_swarm_hash,
        sequence=sequence,
        timestamp_ns=timestamp_ns,
        x_m=x_m,
        y_m=y_m,
        theta_rad=theta_rad,
        xdot_mps=xdot_mps,
        ydot_mps=ydot_mps,
        thetadot_radps=thetadot_radps,
        localised=bool(flags & FLAG_LOCALISED),
    )
    problem = content_problem(frame)
    return frame if problem is None else problem

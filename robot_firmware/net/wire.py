"""Pin-level messages between the world and a robot's fabric, and the world's clock.

Each is an explicit little-endian `struct` layout with a version byte.

    sense  (world -> fabric)  version u8, n_sonar u8, flags u8 (bit0 fix present, bit1 fix
                              valid, bit2 lockstep), radio frames delivered with it u8,
                              tick u64, t_ns u64,
                              encoder counts 4 x i64, fix x_m, y_m, heading_rad 3 x f64,
                              fix stamp_ns u64,
                              then n_sonar x f32 echo times in seconds (< 0: no echo),
                              then the world's epoch u32
    act    (fabric -> world)  version u8, enabled bits u8, watchdog expired u8,
                              radio frames sent this tick u8, tick u64, duty 4 x f64

The frame counts let lockstep be deterministic: radio frames travel on their own keys, so a
receiver waits until it holds as many frames as the message announces before it goes on.
    clock  (world -> all)     version u8, lockstep u8, pad u16, tick u64, t_ns u64, dt_ns u64,
                              epoch u32

The epoch names one start of the world process (DESIGN.md §7.1): a world restarted from a
checkpoint, or from nothing, sends another one, and its clock may have jumped backwards or
forwards; a robot that sees a new epoch re-synchronises to the new time.  Version 2 added it.

Sending every robot's sense message at once: `encode_sense_rows` fills one numpy structured
array (`sense_layout`, the same bytes as `encode_sense`) from the world's arrays (`SensePins`),
column by column, and cuts it into one payload per robot: no per-robot, per-field Python work.

Receiving: `parse_sense`, `parse_act` and `parse_clock` never raise.  Each returns the message
or the first `WireDropReason` that refuses it, checks in this order: bytes-like (`not_bytes`);
length (`too_short`, `too_long`; a sense message's length follows from its sonar count);
version (`unsupported_version`); sonar count above `MAX_SONAR` (`too_many_sonars`); flag, enable
or pad bits that mean nothing (`reserved_bits`); a sonar count other than the receiver's
(`wrong_sonar_count`, when it names one); NaN or infinity (`non_finite`); values no world
sends (`out_of_range`: a duty outside [-1, 1], a fix farther than `MAX_ABS_FIX_M` from the
origin on an axis, an echo later than `MAX_ECHO_TIME_S`, a clock step of zero).  The receiver
counts the drop in a `WireCounters`; `unknown_robot` is the world's own reason for an act
message on a key that names no robot of the scenario.  `decode_*` are the same checks for
callers that only need the message (None when refused).
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from numpy.typing import NDArray

WIRE_VERSION = 2
EPOCH_MAX = 0xFFFF_FFFF
MAX_SONAR = 64
MAX_ABS_FIX_M = 1.0e4
"""Largest |x| or |y| of a positioning fix, metres (the radio frames' bound)."""
MAX_ECHO_TIME_S = 1.0
"""Latest sonar echo, seconds: about 170 m of sound path, far beyond any transducer's range."""

_SENSE_HEAD = struct.Struct("<BBBBQQ4q3dQ")
_ACT = struct.Struct("<BBBBQ4d")
_CLOCK = struct.Struct("<BBHQQQI")
_EPOCH = struct.Struct("<I")

_FIX_PRESENT = 1
_FIX_VALID = 2
_LOCKSTEP = 4
_SENSE_FLAGS = _FIX_PRESENT | _FIX_VALID | _LOCKSTEP


class WireDropReason(enum.Enum):
    """Why a received wire message was refused, in the order the checks run."""

    NOT_BYTES = "not_bytes"
    TOO_SHORT = "too_short"
    TOO_LONG = "too_long"
    UNSUPPORTED_VERSION = "unsupported_version"
    TOO_MANY_SONARS = "too_many_sonars"
    RESERVED_BITS = "reserved_bits"
    WRONG_SONAR_COUNT = "wrong_sonar_count"
    NON_FINITE = "non_finite"
    OUT_OF_RANGE = "out_of_range"
    UNKNOWN_ROBOT = "unknown_robot"


_WIRE_DROP_REASON_VALUES = {reason: reason.value for reason in WireDropReason}
"""Each reason's value, looked up once (an enum's `.value` is a descriptor call)."""


@dataclass(slots=True)
class WireCounters:
    """Messages of one kind seen by one receiver: accepted, and refused per reason (every
    reason present)."""

    accepted: int = 0
    dropped: dict[WireDropReason, int] = field(
        default_factory=lambda: dict.fromkeys(WireDropReason, 0)
    )

    def count(self, outcome: object) -> None:
        """Count one message: a `WireDropReason` as that drop, anything else as accepted."""
        if isinstance(outcome, WireDropReason):
            self.dropped[outcome] += 1
        else:
            self.accepted += 1

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())

    def dropped_as_dict(self) -> dict[str, int]:
        """One entry per reason value, for telemetry and summary.json."""
        values = _WIRE_DROP_REASON_VALUES
        return {values[reason]: count for reason, count in self.dropped.items()}


@dataclass(frozen=True)
class FixSample:
    """A positioning fix as the tracking system sends it."""

    x_m: float
    y_m: float
    heading_rad: float
    stamp_ns: int
    valid: bool = True


@dataclass(frozen=True)
class SenseMessage:
    """What one robot's pins see at one instant: running 4x encoder counts, sonar echo times
    (None: no echo), and a positioning fix when a new one is out (None otherwise)."""

    encoder_counts: tuple[int, ...]
    sonar_echo_times_s: tuple[float | None, ...]
    fix: FixSample | None
    tick: int = 0
    t_ns: int = 0
    lockstep: bool = False
    radio_frames: int = 0
    epoch: int = 0


@dataclass(frozen=True)
class ActMessage:
    """What one robot's motor pins carry after a control tick."""

    tick: int
    duty: tuple[float, float, float, float]
    enabled: tuple[bool, bool, bool, bool]
    watchdog_expired: bool
    radio_frames: int = 0


@dataclass(frozen=True)
class ClockMessage:
    """The world's simulation time; in lockstep, the tick every robot must answer."""

    tick: int
    t_ns: int
    dt_ns: int
    lockstep: bool
    epoch: int = 0


def encode_sense(message: SenseMessage) -> bytes:
    fix = message.fix
    flags = _LOCKSTEP if message.lockstep else 0
    x = y = heading = 0.0
    stamp = 0
    if fix is not None:
        flags |= _FIX_PRESENT | (_FIX_VALID if fix.valid else 0)
        x, y, heading, stamp = fix.x_m, fix.y_m, fix.heading_rad, fix.stamp_ns
    echoes = [-1.0 if t is None else t for t in message.sonar_echo_times_s]
    head = _SENSE_HEAD.pack(
        WIRE_VERSION,
        len(echoes),
        flags,
        min(message.radio_frames, 255),
        message.tick,
        message.t_ns,
        *message.encoder_counts,
        x,
        y,
        heading,
        stamp,
    )
    return head + struct.pack(f"<{len(echoes)}f", *echoes) + _EPOCH.pack(message.epoch)


@cache
def sense_layout(n_sonar: int) -> np.dtype:
    """One sense message as a packed little-endian numpy record: the layout of `_SENSE_HEAD`,
    the echo times and the epoch, field for field (module docstring)."""
    layout = np.dtype(
        [
            ("version", "u1"),
            ("n_sonar", "u1"),
            ("flags", "u1"),
            ("radio_frames", "u1"),
            ("tick", "<u8"),
            ("t_ns", "<u8"),
            ("encoder_counts", "<i8", (4,)),
            ("fix", "<f8", (3,)),
            ("fix_stamp_ns", "<u8"),
            ("echo_times_s", "<f4", (n_sonar,)),
            ("epoch", "<u4"),
        ]
    )
    assert layout.itemsize == _SENSE_HEAD.size + 4 * n_sonar + _EPOCH.size
    return layout


@dataclass(frozen=True)
class SensePins:
    """What every robot's pins see at one instant, as the world holds it: one row per robot."""

    encoder_counts: NDArray[np.int64]
    """(N, 4) running 4x counts."""
    echo_times_s: NDArray[np.float64]
    """(N, sonars) round-trip echo times; NaN: no echo."""
    fix_pose: NDArray[np.float64] | None
    """(N, 3) x_m, y_m, heading_rad of a new positioning fix, or None when none is out."""
    fix_valid: NDArray[np.bool_]
    """(N,) whether each robot's fix is valid (the world can cut it)."""
    t_ns: int
    """The instant, also the fixes' stamp."""

    def messages(
        self,
        tick: int = 0,
        lockstep: bool = False,
        radio_frames: Sequence[int] = (),
        epoch: int = 0,
    ) -> list[SenseMessage]:
        """The same as `SenseMessage`s (for in-process callers)."""
        frames = list(radio_frames) or [0] * len(self.encoder_counts)
        out = []
        for i, counts in enumerate(self.encoder_counts):
            fix = None
            if self.fix_pose is not None:
                x, y, heading = (float(v) for v in self.fix_pose[i])
                fix = FixSample(x, y, heading, self.t_ns, valid=bool(self.fix_valid[i]))
            out.append(
                SenseMessage(
                    encoder_counts=tuple(int(c) for c in counts),
                    sonar_echo_times_s=tuple(
                        None if math.isnan(t) else float(t) for t in self.echo_times_s[i]
                    ),
                    fix=fix,
                    tick=tick,
                    t_ns=self.t_ns,
                    lockstep=lockstep,
                    radio_frames=frames[i],
                    epoch=epoch,
                )
            )
        return out


def encode_sense_rows(
    pins: SensePins, tick: int, lockstep: bool, radio_frames: Sequence[int], epoch: int
) -> list[bytes]:
    """Every robot's sense message, byte for byte what `encode_sense` gives for each row, built
    as one structured array."""
    robots, n_sonar = pins.echo_times_s.shape
    rows = np.zeros(robots, dtype=sense_layout(n_sonar))
    rows["version"] = WIRE_VERSION
    rows["n_sonar"] = n_sonar
    flags = np.full(robots, _LOCKSTEP if lockstep else 0, dtype=np.uint8)
    if pins.fix_pose is not None:
        flags |= np.where(pins.fix_valid, _FIX_PRESENT | _FIX_VALID, _FIX_PRESENT).astype(np.uint8)
        rows["fix"] = pins.fix_pose
        rows["fix_stamp_ns"] = pins.t_ns
    rows["flags"] = flags
    rows["radio_frames"] = np.minimum(np.asarray(radio_frames, dtype=np.int64), 255)
    rows["tick"] = tick
    rows["t_ns"] = pins.t_ns
    rows["encoder_counts"] = pins.encoder_counts
    echoes = pins.echo_times_s
    rows["echo_times_s"] = np.where(np.isnan(echoes), -1.0, echoes)
    rows["epoch"] = epoch
    raw = rows.tobytes()
    size = rows.itemsize
    return [raw[i * size : (i + 1) * size] for i in range(robots)]


def parse_sense(data: object, sonar_count: int | None = None) -> SenseMessage | WireDropReason:
    """The sense message in `data`, or why it is refused; `sonar_count`: the receiver's
    transducers (None: any count up to `MAX_SONAR`)."""
    raw = _as_bytes(data)
    if raw is None:
        return WireDropReason.NOT_BYTES
    if len(raw) < _SENSE_HEAD.size:
        return WireDropReason.TOO_SHORT
    version, n_sonar, flags, radio_frames, tick, t_ns, c0, c1, c2, c3, x, y, heading, stamp = (
        _SENSE_HEAD.unpack_from(raw)
    )
    if version != WIRE_VERSION:
        return WireDropReason.UNSUPPORTED_VERSION
    if n_sonar > MAX_SONAR:
        return WireDropReason.TOO_MANY_SONARS
    size = _SENSE_HEAD.size + 4 * n_sonar + _EPOCH.size
    if len(raw) != size:
        return WireDropReason.TOO_SHORT if len(raw) < size else WireDropReason.TOO_LONG
    if flags & ~_SENSE_FLAGS:
        return WireDropReason.RESERVED_BITS
    if sonar_count is not None and n_sonar != sonar_count:
        return WireDropReason.WRONG_SONAR_COUNT
    echoes = struct.unpack_from(f"<{n_sonar}f", raw, _SENSE_HEAD.size)
    (epoch,) = _EPOCH.unpack_from(raw, size - _EPOCH.size)
    if not all(math.isfinite(v) for v in (x, y, heading, *echoes)):
        return WireDropReason.NON_FINITE
    if (
        abs(x) > MAX_ABS_FIX_M
        or abs(y) > MAX_ABS_FIX_M
        or max(echoes, default=0.0) > MAX_ECHO_TIME_S
    ):
        return WireDropReason.OUT_OF_RANGE
    fix = None
    if flags & _FIX_PRESENT:
        fix = FixSample(x, y, heading, stamp, valid=bool(flags & _FIX_VALID))
    return SenseMessage(
        encoder_counts=(c0, c1, c2, c3),
        sonar_echo_times_s=tuple(None if t < 0.0 else float(t) for t in echoes),
        fix=fix,
        tick=tick,
        t_ns=t_ns,
        lockstep=bool(flags & _LOCKSTEP),
        radio_frames=radio_frames,
        epoch=epoch,
    )


def decode_sense(data: object, sonar_count: int | None = None) -> SenseMessage | None:
    message = parse_sense(data, sonar_count)
    return None if isinstance(message, WireDropReason) else message


def encode_act(message: ActMessage) -> bytes:
    bits = sum(1 << i for i, on in enumerate(message.enabled) if on)
    return _ACT.pack(
        WIRE_VERSION,
        bits,
        int(message.watchdog_expired),
        min(message.radio_frames, 255),
        message.tick,
        *message.duty,
    )


def parse_act(data: object) -> ActMessage | WireDropReason:
    """The act message in `data`, or why it is refused."""
    raw = _as_bytes(data)
    if raw is None:
        return WireDropReason.NOT_BYTES
    if len(raw) != _ACT.size:
        return WireDropReason.TOO_SHORT if len(raw) < _ACT.size else WireDropReason.TOO_LONG
    version, bits, expired, radio_frames, tick, d0, d1, d2, d3 = _ACT.unpack(raw)
    duty = (d0, d1, d2, d3)
    if version != WIRE_VERSION:
        return WireDropReason.UNSUPPORTED_VERSION
    if bits > 0xF or expired > 1:
        return WireDropReason.RESERVED_BITS
    if not all(math.isfinite(d) for d in duty):
        return WireDropReason.NON_FINITE
    if not all(-1.0 <= d <= 1.0 for d in duty):
        return WireDropReason.OUT_OF_RANGE
    enabled = tuple(bool(bits >> i & 1) for i in range(4))
    return ActMessage(
        tick=tick,
        duty=duty,
        enabled=(enabled[0], enabled[1], enabled[2], enabled[3]),
        watchdog_expired=bool(expired),
        radio_frames=radio_frames,
    )


def decode_act(data: object) -> ActMessage | None:
    message = parse_act(data)
    return None if isinstance(message, WireDropReason) else message


def encode_clock(message: ClockMessage) -> bytes:
    return _CLOCK.pack(
        WIRE_VERSION,
        int(message.lockstep),
        0,
        message.tick,
        message.t_ns,
        message.dt_ns,
        message.epoch,
    )


def parse_clock(data: object) -> ClockMessage | WireDropReason:
    """The clock message in `data`, or why it is refused."""
    raw = _as_bytes(data)
    if raw is None:
        return WireDropReason.NOT_BYTES
    if len(raw) != _CLOCK.size:
        return WireDropReason.TOO_SHORT if len(raw) < _CLOCK.size else WireDropReason.TOO_LONG
    version, lockstep, pad, tick, t_ns, dt_ns, epoch = _CLOCK.unpack(raw)
    if version != WIRE_VERSION:
        return WireDropReason.UNSUPPORTED_VERSION
    if lockstep > 1 or pad:
        return WireDropReason.RESERVED_BITS
    if dt_ns == 0:
        return WireDropReason.OUT_OF_RANGE
    return ClockMessage(tick=tick, t_ns=t_ns, dt_ns=dt_ns, lockstep=bool(lockstep), epoch=epoch)


def decode_clock(data: object) -> ClockMessage | None:
    message = parse_clock(data)
    return None if isinstance(message, WireDropReason) else message


def _as_bytes(data: object) -> bytes | None:
    if not isinstance(data, bytes | bytearray | memoryview):
        return None
    try:
        return bytes(data)
    except (TypeError, ValueError):  # e.g. a released memoryview
        return None

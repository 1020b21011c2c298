"""Pin-level messages between the world and a robot's fabric, and the world's clock.

Each is an explicit little-endian `struct` layout with a version byte.  A decoder returns None
for anything malformed (wrong length, unknown version, non-finite values) and never raises; the
caller counts the drop.

    sense  (world -> fabric)  version u8, n_sonar u8, flags u8 (bit0 fix present, bit1 fix
                              valid, bit2 lockstep), radio frames delivered with it u8,
                              tick u64, t_ns u64,
                              encoder counts 4 x i64, fix x_m, y_m, heading_rad 3 x f64,
                              fix stamp_ns u64,
                              then n_sonar x f32 echo times in seconds (< 0: no echo)
    act    (fabric -> world)  version u8, enabled bits u8, watchdog expired u8,
                              radio frames sent this tick u8, tick u64, duty 4 x f64

The frame counts let lockstep be deterministic: radio frames travel on their own keys, so a
receiver waits until it holds as many frames as the message announces before it goes on.
    clock  (world -> all)     version u8, lockstep u8, pad u16, tick u64, t_ns u64, dt_ns u64
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

WIRE_VERSION = 1
MAX_SONAR = 64

_SENSE_HEAD = struct.Struct("<BBBBQQ4q3dQ")
_ACT = struct.Struct("<BBBBQ4d")
_CLOCK = struct.Struct("<BBHQQQ")

_FIX_PRESENT = 1
_FIX_VALID = 2
_LOCKSTEP = 4


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
    return head + struct.pack(f"<{len(echoes)}f", *echoes)


def decode_sense(data: bytes) -> SenseMessage | None:
    try:
        if len(data) < _SENSE_HEAD.size:
            return None
        version, n_sonar, flags, radio_frames, tick, t_ns, c0, c1, c2, c3, x, y, heading, stamp = (
            _SENSE_HEAD.unpack_from(data)
        )
        if version != WIRE_VERSION or n_sonar > MAX_SONAR or flags & ~7:
            return None
        if len(data) != _SENSE_HEAD.size + 4 * n_sonar:
            return None
        echoes = struct.unpack_from(f"<{n_sonar}f", data, _SENSE_HEAD.size)
        if not all(math.isfinite(v) for v in (x, y, heading, *echoes)):
            return None
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
        )
    except (struct.error, TypeError):
        return None


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


def decode_act(data: bytes) -> ActMessage | None:
    try:
        if len(data) != _ACT.size:
            return None
        version, bits, expired, radio_frames, tick, d0, d1, d2, d3 = _ACT.unpack(data)
        duty = (d0, d1, d2, d3)
        if version != WIRE_VERSION or bits > 0xF or expired > 1:
            return None
        if not all(math.isfinite(d) and -1.0 <= d <= 1.0 for d in duty):
            return None
        enabled = tuple(bool(bits >> i & 1) for i in range(4))
        return ActMessage(
            tick=tick,
            duty=duty,
            enabled=(enabled[0], enabled[1], enabled[2], enabled[3]),
            watchdog_expired=bool(expired),
            radio_frames=radio_frames,
        )
    except (struct.error, TypeError):
        return None


def encode_clock(message: ClockMessage) -> bytes:
    return _CLOCK.pack(
        WIRE_VERSION, int(message.lockstep), 0, message.tick, message.t_ns, message.dt_ns
    )


def decode_clock(data: bytes) -> ClockMessage | None:
    try:
        if len(data) != _CLOCK.size:
            return None
        version, lockstep, _, tick, t_ns, dt_ns = _CLOCK.unpack(data)
        if version != WIRE_VERSION or lockstep > 1:
            return None
        return ClockMessage(tick=tick, t_ns=t_ns, dt_ns=dt_ns, lockstep=bool(lockstep))
    except (struct.error, TypeError):
        return None

"""What the radio medium puts on `radio/rx/<robot>`: the frames one pass has for that robot.

The world's radio medium (world/runtime.py) passes frames on in passes: in lockstep every
frame due at a tick boundary at once, in real time whatever a pass of the relay finds due.
The frames one pass has for one receiver go out as one message, a bundle, instead of one
message per frame: the same frames, in the same order, at the same moment, with one put by the
world, one delivery by the router and one receive by the robot instead of one per frame (at
24 robots in lockstep about 12 frames per receiver and tick; docs/scale.md, "The radio medium's
bundles").

Layout: one or more records, end to end, each

| bytes | struct | field  | meaning                                          |
|------:|--------|--------|--------------------------------------------------|
|     4 | I      | length | the frame's length in bytes, little-endian       |
|     n | n s    | frame  | the frame as its sender transmitted it (opaque)  |

The medium does not look into frames (robot_firmware/net/frames.py decodes them), so a record
holds whatever the sender put, of any length.  A bundle is at most `BUNDLE_BYTES_MAX` bytes
unless a single frame is longer (then that frame goes alone): a pass after a long stall of the
world's loop may have hundreds of frames for one robot, and the router refuses messages over
1 MiB (services/router/access.py).

Receiving: `split_bundle` never raises.  It returns the frames of a well-formed bundle in
order.  A message that is not one (empty, or a record whose length runs past the end) gives
the frames before the fault and then the rest of the message as one more frame, which the
frame decoder drops and counts (`too_short`, or whatever its first check finds); so every
malformed bundle is dropped and counted where frames are, and a well-formed record is never
lost to a fault after it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

RECORD_HEADER = struct.Struct("<I")
"""The length before each frame of a bundle."""
BUNDLE_BYTES_MAX = 64 << 10
"""The largest bundle `bundle_frames` makes, unless a single frame is longer."""
FRAME_RING = 1024
"""Bundles Zenoh holds for a robot's loop between two of its passes (the oldest dropped)."""


def bundle_frames(frames: Iterable[bytes]) -> list[bytes]:
    """The frames, in order, as few bundles as fit `BUNDLE_BYTES_MAX` (none for no frames)."""
    bundles: list[bytes] = []
    parts: list[bytes] = []
    size = 0
    pack = RECORD_HEADER.pack
    header_bytes = RECORD_HEADER.size
    for frame in frames:
        record_bytes = header_bytes + len(frame)
        if parts and size + record_bytes > BUNDLE_BYTES_MAX:
            bundles.append(b"".join(parts))
            parts, size = [], 0
        parts.append(pack(len(frame)))
        parts.append(frame)
        size += record_bytes
    if parts:
        bundles.append(b"".join(parts))
    return bundles


def split_bundle(data: bytes) -> list[bytes]:
    """The frames of bundle `data`, in order; a malformed rest as one more frame (see above)."""
    frames: list[bytes] = []
    end = len(data)
    if end == 0:
        return [b""]
    header_bytes = RECORD_HEADER.size
    unpack_from = RECORD_HEADER.unpack_from
    offset = 0
    while offset < end:
        start = offset + header_bytes
        if start > end:
            frames.append(data[offset:])
            break
        (length,) = unpack_from(data, offset)
        offset = start + length
        if offset > end:
            frames.append(data[start - header_bytes :])
            break
        frames.append(data[start:offset])
    return frames

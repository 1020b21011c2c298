"""Where a `.rrd` recording cut off by a kill stops being whole, and cutting the rest off.

A Rerun recording file (the "RRF2" encoding of rerun-sdk 0.2x-0.4x) is a 12-byte stream header
(`RRF2`, the writer's version, the encoding options) followed by messages. Each message is a
16-byte header, its kind and its payload length as two little-endian u64, and then the payload.
A writer that stops cleanly ends the stream with an `End` message (kind 0) that carries the
footer, and a fixed trailer.

The dashboard's file sink writes one message in more than one write, so a writer killed between
them (or a file read while it is being written) ends in a partial message: a header without all
of its payload, or part of a header. Rerun's viewer and `rerun rrd` stop at such a tail and keep
the rest; `rerun.chunk.RrdReader` refuses the whole file. `whole_messages_length` walks the
message headers (it reads headers only, never payloads) to where the last whole message ends;
`trim_partial_message` truncates a file there. A file that does not start as this encoding does,
or whose headers do not make sense, is reported as not understood and left as it is.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import BinaryIO

STREAM_MAGIC = b"RRF2"
STREAM_HEADER_BYTES = 12
MESSAGE_HEADER = struct.Struct("<QQ")
END_KIND = 0
KNOWN_KINDS = frozenset({END_KIND, 1, 2, 3})
"""End, store info, Arrow chunk, blueprint activation."""


def whole_messages_length(stream: BinaryIO) -> int | None:
    """Bytes from the start of `stream` that hold whole messages; the whole size once the
    `End` message is whole. None when the stream is not an RRF2 recording or a header names an
    unknown kind."""
    size = stream.seek(0, os.SEEK_END)
    stream.seek(0)
    if stream.read(len(STREAM_MAGIC)) != STREAM_MAGIC or size < STREAM_HEADER_BYTES:
        return None
    offset = STREAM_HEADER_BYTES
    while offset + MESSAGE_HEADER.size <= size:
        stream.seek(offset)
        kind, payload_bytes = MESSAGE_HEADER.unpack(stream.read(MESSAGE_HEADER.size))
        if kind not in KNOWN_KINDS:
            return None
        end = offset + MESSAGE_HEADER.size + payload_bytes
        if end > size:
            return offset
        if kind == END_KIND:
            return size
        offset = end
    return offset


RECORDING_MAGIC_PREFIX = b"RRF"
"""How every encoding of Rerun's recording files starts (then its version digit)."""


def looks_like_recording(path: Path) -> bool:
    """Whether the file starts as a Rerun recording of any encoding version does (it may still
    be cut off or of a version this Rerun cannot read; the viewer says so)."""
    with path.open("rb") as stream:
        return stream.read(len(RECORDING_MAGIC_PREFIX)) == RECORDING_MAGIC_PREFIX


def trim_partial_message(path: Path) -> int:
    """Truncate the recording at `path` to its whole messages; return the bytes cut off (0 for
    a whole file and for one this module does not understand)."""
    with path.open("rb") as stream:
        whole = whole_messages_length(stream)
        size = stream.seek(0, os.SEEK_END)
    if whole is None or whole >= size:
        return 0
    os.truncate(path, whole)
    return size - whole


def whole_messages(path: Path) -> bytes:
    """The whole messages of a recording that may still be being written (b"" when the file is
    not understood)."""
    with path.open("rb") as stream:
        whole = whole_messages_length(stream)
        if not whole:
            return b""
        stream.seek(0)
        return stream.read(whole)

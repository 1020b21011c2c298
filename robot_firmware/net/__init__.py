"""Robot networking: the radio frame codec (pure) and, later, the glue to the radio medium."""

from robot_firmware.net.frames import (
    FRAME_BYTES,
    DropReason,
    FrameCounters,
    FrameDecoder,
    RadioFrame,
    Role,
    derive_frame_key,
    encode,
    key_from_secret,
    parse_frame,
    swarm_hash_from_name,
)

__all__ = [
    "FRAME_BYTES",
    "DropReason",
    "FrameCounters",
    "FrameDecoder",
    "RadioFrame",
    "Role",
    "derive_frame_key",
    "encode",
    "key_from_secret",
    "parse_frame",
    "swarm_hash_from_name",
]

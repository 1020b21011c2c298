"""Radio bundles (robot_firmware/net/radio_bundle.py): the frames of one pass of the medium in
one `radio/rx` message; round trip, size limit, and malformed bundles dropped and counted by
the frame decoder, never raised on."""

from __future__ import annotations

import itertools
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_firmware.net.frames import FRAME_BYTES, DropReason, encode
from robot_firmware.net.radio_bundle import (
    BUNDLE_BYTES_MAX,
    RECORD_HEADER,
    bundle_frames,
    split_bundle,
)
from tests.net.test_frames import KEY, NOW_NS, make_frame, new_decoder

any_frames = st.lists(st.binary(max_size=300), max_size=40)


def signed_frames(count: int) -> list[bytes]:
    """`count` authentic frames of sender 1, one millisecond apart, in sequence."""
    return [
        encode(make_frame(sequence=100 + k, timestamp_ns=NOW_NS - 1_000_000 * (count - k)), KEY)
        for k in range(count)
    ]


def test_layout_is_a_little_endian_length_before_each_frame() -> None:
    (bundle,) = bundle_frames([b"abc", b"", b"\x00" * 5])
    assert bundle == (
        struct.pack("<I", 3) + b"abc" + struct.pack("<I", 0) + struct.pack("<I", 5) + bytes(5)
    )
    assert RECORD_HEADER.size == 4


@given(any_frames)
def test_split_inverts_bundle_frame_for_frame_in_order(frames: list[bytes]) -> None:
    bundles = bundle_frames(frames)
    assert [f for bundle in bundles for f in split_bundle(bundle)] == frames
    assert len(bundles) == (1 if frames else 0)  # these all fit in one


@settings(max_examples=30)
@given(st.lists(st.integers(min_value=0, max_value=3 * BUNDLE_BYTES_MAX), max_size=12))
def test_a_bundle_stays_under_its_limit_unless_one_frame_alone_is_over(sizes: list[int]) -> None:
    frames = [bytes([k % 251]) * size for k, size in enumerate(sizes)]
    bundles = bundle_frames(frames)
    assert [f for bundle in bundles for f in split_bundle(bundle)] == frames
    for bundle in bundles:
        pieces = split_bundle(bundle)
        assert len(bundle) <= BUNDLE_BYTES_MAX or len(pieces) == 1
    # As few bundles as the limit allows: no two neighbours would have fitted in one.
    for first, second in itertools.pairwise(bundles):
        assert len(first) + len(second) > BUNDLE_BYTES_MAX


def test_frames_of_a_long_stall_go_in_several_bundles_in_order() -> None:
    frames = signed_frames(2_000)
    bundles = bundle_frames(frames)
    per_bundle = BUNDLE_BYTES_MAX // (RECORD_HEADER.size + FRAME_BYTES)
    assert [len(split_bundle(b)) for b in bundles] == [per_bundle] * 3 + [2_000 - 3 * per_bundle]
    assert [f for b in bundles for f in split_bundle(b)] == frames


def test_an_empty_message_is_one_empty_frame_which_the_decoder_counts() -> None:
    assert split_bundle(b"") == [b""]
    decoder = new_decoder()
    assert decoder.decode(b"", NOW_NS) is None
    assert decoder.counters.dropped[DropReason.TOO_SHORT] == 1


def test_every_cut_of_a_bundle_keeps_the_whole_frames_and_counts_the_rest_once() -> None:
    """A bundle of three authentic frames cut at every length: the frames wholly before the
    cut are accepted, in order; a rest is one more piece, dropped and counted."""
    frames = signed_frames(3)
    (bundle,) = bundle_frames(frames)
    record_bytes = RECORD_HEADER.size + FRAME_BYTES
    for cut in range(1, len(bundle) + 1):
        pieces = split_bundle(bundle[:cut])
        whole = cut // record_bytes
        rest = cut % record_bytes
        assert pieces[:whole] == frames[:whole], cut
        assert len(pieces) == whole + (1 if rest else 0), cut
        decoder = new_decoder()
        accepted = [decoder.decode(piece, NOW_NS) for piece in pieces]
        assert sum(frame is not None for frame in accepted) == whole, cut
        assert decoder.counters.dropped_total == (1 if rest else 0), cut


@given(st.binary(max_size=2_000))
def test_any_bytes_split_into_pieces_that_are_accepted_or_counted(data: bytes) -> None:
    pieces = split_bundle(data)
    assert pieces  # an empty message is a piece too: every message is counted somewhere
    assert sum(len(p) for p in pieces) <= len(data)
    decoder = new_decoder()
    for piece in pieces:
        decoder.decode(piece, NOW_NS)
    assert decoder.counters.total == len(pieces)

"""A recording cut anywhere is trimmed to its whole messages, which Rerun's reader opens."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import pytest
from rerun.error_utils import RerunWarning

from services.dashboard.recording_file import (
    MESSAGE_HEADER,
    STREAM_HEADER_BYTES,
    trim_partial_message,
    whole_messages,
    whole_messages_length,
)
from tests.dashboard.conftest import FINISHED_RECORDING_CHUNKS as CHUNKS
from tests.dashboard.conftest import message_ends, read_recording


def _read_rows(path: Path) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RerunWarning)  # a file without footer is a legacy file
        robot = read_recording(path).get("/map/robots/robot1")
    return robot.rows if robot else 0


def test_a_finished_recording_is_whole_and_left_alone(
    finished_recording: bytes, tmp_path: Path
) -> None:
    path = tmp_path / "dashboard.rrd"
    path.write_bytes(finished_recording)
    with path.open("rb") as stream:
        assert whole_messages_length(stream) == len(finished_recording)
    assert trim_partial_message(path) == 0
    assert path.read_bytes() == finished_recording
    assert _read_rows(path) == CHUNKS


def test_a_recording_cut_anywhere_is_trimmed_to_the_last_whole_message(
    finished_recording: bytes, tmp_path: Path
) -> None:
    ends = message_ends(finished_recording)
    before_end = ends[-2]  # what a kill between two flushes leaves: no End, no footer
    cuts = sorted({*range(STREAM_HEADER_BYTES, before_end, 97), *ends[:-1], before_end})
    rows_seen = []
    for cut in cuts:
        path = tmp_path / f"cut-{cut}.rrd"
        path.write_bytes(finished_recording[:cut])
        whole = max(end for end in [STREAM_HEADER_BYTES, *ends] if end <= cut)
        assert whole_messages(path) == finished_recording[:whole], cut
        assert trim_partial_message(path) == cut - whole, cut
        assert path.read_bytes() == finished_recording[:whole], cut
        if whole > STREAM_HEADER_BYTES:
            rows_seen.append(_read_rows(path))
    assert rows_seen == sorted(rows_seen) and rows_seen[-1] == CHUNKS


def test_a_cut_recording_is_what_rerun_reader_refuses_untrimmed(
    finished_recording: bytes, tmp_path: Path
) -> None:
    ends = message_ends(finished_recording)
    path = tmp_path / "cut.rrd"
    path.write_bytes(finished_recording[: ends[-3] + MESSAGE_HEADER.size + 3])
    with pytest.raises(RuntimeError, match="exceeds file size"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RerunWarning)
        read_recording(path)
    assert trim_partial_message(path) == MESSAGE_HEADER.size + 3
    assert _read_rows(path) == CHUNKS - 1


@pytest.mark.parametrize(
    "content",
    [
        b"",
        b"not a recording at all",
        b"RRF2" + bytes(8) + struct.pack("<QQ", 99, 4) + b"abcd" + b"tail",
    ],
    ids=["empty", "other-format", "unknown-kind"],
)
def test_a_file_that_is_not_understood_is_left_as_it_is(content: bytes, tmp_path: Path) -> None:
    path = tmp_path / "dashboard.rrd"
    path.write_bytes(content)
    with path.open("rb") as stream:
        assert whole_messages_length(stream) is None
    assert trim_partial_message(path) == 0
    assert whole_messages(path) == b""
    assert path.read_bytes() == content

"""Hypothesis strategies for byte-level fuzzing: random bytes, and mutants of a valid message.

A mutant keeps most of a valid message so that it reaches the checks past the length and the
version: bits flipped, bytes overwritten, a float field set to NaN, infinity or a huge value,
an integer field set to an extreme, the message cut short or extended.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from hypothesis import strategies as st

SPECIAL_DOUBLES = (math.nan, math.inf, -math.inf, 1e308, -1e308, 2.0, -2.0, 1e5, 5e-324)
SPECIAL_WORDS = (0, 1, 0x7F, 0x80, 0xFF, 0xFFFF, 0xFFFF_FFFF)


@st.composite
def mutants(
    draw: st.DrawFn, valid: st.SearchStrategy[bytes], double_offsets: Sequence[int] = ()
) -> bytes:
    """A valid message from `valid` with one to three mutations."""
    data = bytearray(draw(valid))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(("flip", "byte", "double", "word", "cut", "extend")))
        if kind == "flip" and data:
            i = draw(st.integers(0, len(data) - 1))
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "byte" and data:
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        elif kind == "double" and double_offsets:
            at = draw(st.sampled_from(double_offsets))
            if at + 8 <= len(data):
                value = draw(st.sampled_from(SPECIAL_DOUBLES) | st.floats(width=64))
                struct.pack_into("<d", data, at, value)
        elif kind == "word" and len(data) >= 4:
            at = draw(st.integers(0, len(data) - 4))
            struct.pack_into("<I", data, at, draw(st.sampled_from(SPECIAL_WORDS)))
        elif kind == "cut":
            del data[draw(st.integers(0, len(data))) :]
        else:
            data += draw(st.binary(min_size=1, max_size=16))
    return bytes(data)


def random_or_mutant(
    valid: st.SearchStrategy[bytes], double_offsets: Sequence[int] = (), max_size: int = 400
) -> st.SearchStrategy[bytes]:
    """Half random bytes, half mutants of valid messages (plus the valid ones themselves)."""
    return st.one_of(
        st.binary(max_size=max_size),
        mutants(valid, double_offsets),
        valid,
    )

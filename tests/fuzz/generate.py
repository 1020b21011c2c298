"""Seeded generators of fuzz inputs, cheap enough for 10,000 inputs per target.

Hypothesis's machinery costs about a millisecond per example here, so each target's 10,000
inputs come from these generators (a `random.Random` with a fixed seed: the same inputs on
every run), and a smaller hypothesis test per target adds shrinking.  Inputs are random data,
and mutants of valid ones that keep most of the structure so they reach the later checks:

* bytes: bits flipped, bytes or words overwritten, a float field set to NaN, infinity or a huge
  value, the message cut short or extended;
* JSON values: one node replaced by a value of another type, NaN or infinity, an extreme
  number, a huge string or array, a key removed or an unknown one added;
* text (YAML or JSON files): lines dropped, repeated or swapped, characters inserted, a YAML
  construct that trips loaders (a date that does not exist, deep nesting, tags, anchors).
"""

from __future__ import annotations

import json
import math
import random
import struct
from collections.abc import Callable, Iterator, Sequence
from typing import Any

SPECIAL_DOUBLES = (math.nan, math.inf, -math.inf, 1e308, -1e308, 2.0, -2.0, 1e5, 5e-324, -0.0)
SPECIAL_WORDS = (0, 1, 0x7F, 0x80, 0xFF, 0xFFFF, 0x8000_0000, 0xFFFF_FFFF)

NASTY_JSON: tuple[Any, ...] = (
    None,
    True,
    False,
    0,
    -1,
    2**31,
    2**64,
    -(2**63) - 1,
    10**400,
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    0.5,
    "",
    "x",
    "robot1",
    "robot99",
    "NaN",
    "\u0000",
    "ünïcödé ✓",
    "a" * 5000,
    [],
    [0.0, 0.0],
    [0.0, 0.0, 0.0],
    [math.nan, 0.0, 0.0],
    [1, 2, 3, 4, 5],
    {},
    {"unknown": 1},
)
"""Values a JSON field should not hold (or only just)."""

HUGE_JSON: tuple[Any, ...] = ([0.0] * 20_000, [[0.0, 0.0]] * 2_000, "b" * 100_000)
"""Sizes no message has: drawn by `nasty` one time in fifty (PyYAML takes ~0.1 s over one)."""


def nasty(rng: random.Random) -> Any:
    """A value of NASTY_JSON, or now and then one of HUGE_JSON."""
    return rng.choice(HUGE_JSON) if rng.random() < 0.02 else rng.choice(NASTY_JSON)


def alias_bomb(levels: int) -> str:
    """One line of flow YAML whose last list stands for 10**levels ones: each level's list
    holds the one before ten times through an alias (the "billion laughs")."""
    parts = ["&l0 [" + ", ".join(["1"] * 10) + "]"]
    parts += [f"&l{k} [" + ", ".join([f"*l{k - 1}"] * 10) + "]" for k in range(1, levels + 1)]
    return "[" + ", ".join(parts) + "]"


YAML_TRAPS = (
    alias_bomb(8),
    "2001-02-30",
    "2001-13-01",
    "!!python/object:os.system x",
    "!!binary 'not base64'",
    "&a [*a]",
    "*undefined",
    "{a: 1, a: 2}",
    "? [1, 2]\n: 3",
    "[" * 400 + "]" * 400,
    "{" * 300,
    "\t- tab",
    "\u0000",
    "~",
    "1e400",
    ".nan",
    "-.inf",
    "0x_1",
    "'unterminated",
    "- " * 50 + "x",
    "%YAML 9.9\n---",
    "--- |\n  block",
    "\ufeff",
    "a: b: c",
)
"""YAML fragments that trip loaders: aliases that expand to 10**8 values, dates that do not
exist (PyYAML raises ValueError), nesting deeper than the composer's recursion, tags, anchors,
directives, control characters."""


def random_bytes(rng: random.Random, max_size: int) -> bytes:
    return rng.randbytes(rng.randint(0, max_size))


def mutate_bytes(
    rng: random.Random,
    valid: bytes,
    double_offsets: Sequence[int] = (),
    single_offsets: Sequence[int] = (),
) -> bytes:
    """`valid` with one to three byte-level mutations; a special value may go into the f64
    fields at `double_offsets` or the f32 fields at `single_offsets`."""
    data = bytearray(valid)
    for _ in range(rng.randint(1, 3)):
        kind = rng.randrange(7)
        if kind == 0 and data:
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        elif kind == 1 and data:
            data[rng.randrange(len(data))] = rng.randrange(256)
        elif kind == 2 and double_offsets:
            at = rng.choice(double_offsets)
            if at + 8 <= len(data):
                value = (
                    rng.choice(SPECIAL_DOUBLES) if rng.random() < 0.7 else rng.uniform(-1e6, 1e6)
                )
                struct.pack_into("<d", data, at, value)
        elif kind == 3 and len(data) >= 4:
            struct.pack_into("<I", data, rng.randrange(len(data) - 3), rng.choice(SPECIAL_WORDS))
        elif kind == 4:
            del data[rng.randint(0, len(data)) :]
        elif kind == 5:
            data += rng.randbytes(rng.randint(1, 16))
        elif data:
            data[0] = rng.randrange(256)  # the version or magic byte
    return bytes(data)


def random_json(rng: random.Random, depth: int = 3) -> Any:
    kind = rng.randrange(8 if depth > 0 else 5)
    if kind == 0:
        return nasty(rng)
    if kind == 1:
        return rng.randint(-(2**70), 2**70)
    if kind == 2:
        return rng.uniform(-1e9, 1e9)
    if kind == 3:
        return "".join(rng.choice("ab_-01 xyz\u00e9") for _ in range(rng.randint(0, 12)))
    if kind == 4:
        return rng.choice((True, False, None))
    if kind in (5, 6):
        keys = ("op", "address", "value", "robot", "profile", "loss", "t_s", "x", "")
        return {rng.choice(keys): random_json(rng, depth - 1) for _ in range(rng.randint(0, 4))}
    return [random_json(rng, depth - 1) for _ in range(rng.randint(0, 5))]


def mutate_json(rng: random.Random, value: Any) -> Any:
    """A deep copy of `value` with one node replaced, removed or added."""
    copy = json.loads(json.dumps(value))
    paths = list(_containers(copy))
    if not paths or rng.random() < 0.05:
        return nasty(rng)
    container = rng.choice(paths)
    if isinstance(container, dict):
        if not container or rng.random() < 0.15:
            container[rng.choice(("extra", "unknown_field", ""))] = random_json(rng, 1)
            return copy
        key = rng.choice(list(container))
        if rng.random() < 0.2:
            del container[key]
        else:
            container[key] = _replacement(rng, container[key])
    elif container:
        i = rng.randrange(len(container))
        roll = rng.random()
        if roll < 0.15:
            del container[i]
        elif roll < 0.25:
            container.append(container[i])
        else:
            container[i] = _replacement(rng, container[i])
    else:
        container.append(random_json(rng, 1))
    return copy


def _replacement(rng: random.Random, old: Any) -> Any:
    if isinstance(old, int | float) and not isinstance(old, bool) and rng.random() < 0.5:
        return rng.choice((old * 1_000_000, -old, old + 1, math.nan, math.inf, 1e308, -1e-308))
    return nasty(rng) if rng.random() < 0.7 else random_json(rng, 2)


def _containers(value: Any) -> Iterator[dict[str, Any] | list[Any]]:
    if isinstance(value, dict):
        yield value
        for child in value.values():
            yield from _containers(child)
    elif isinstance(value, list):
        yield value
        for child in value:
            yield from _containers(child)


def json_bytes(value: Any) -> bytes:
    """JSON text as Python writes it (NaN and Infinity included: a careless producer's)."""
    return json.dumps(value).encode()


def mutate_text(rng: random.Random, text: str) -> str:
    """`text` with one to three line- or character-level mutations."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        kind = rng.randrange(7)
        if kind == 0 and lines:
            del lines[rng.randrange(len(lines))]
        elif kind == 1 and lines:
            lines.insert(rng.randrange(len(lines) + 1), rng.choice(lines))
        elif kind == 2 and len(lines) > 1:
            i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif kind == 3 and lines:
            i = rng.randrange(len(lines))
            key, sep, _ = lines[i].partition(":")
            trap = (
                rng.choice(YAML_TRAPS)
                if rng.random() < 0.5
                else json.dumps(rng.choice(NASTY_JSON[:22]))
            )
            lines[i] = f"{key}{sep or ':'} {trap}"
        elif kind == 4 and lines:
            i = rng.randrange(len(lines))
            at = rng.randint(0, len(lines[i]))
            lines[i] = (
                lines[i][:at]
                + rng.choice(("\t", " ", ":", "-", "#", "'", '"', "{", "[", "\x85", "\x00"))
                + lines[i][at:]
            )
        elif kind == 5:
            lines.insert(rng.randrange(len(lines) + 1), rng.choice(YAML_TRAPS))
        elif lines:
            i = rng.randrange(len(lines))
            lines[i] = "  " + lines[i] if rng.random() < 0.5 else lines[i].lstrip()
    return "\n".join(lines) + "\n"


def random_text(rng: random.Random, max_lines: int = 6) -> str:
    pieces = [*YAML_TRAPS, "a: 1", "- x", "key: [1, 2", "{}", "[]", "null", "'q'", "# c", ":"]
    return "\n".join(rng.choice(pieces) for _ in range(rng.randint(0, max_lines)))


def inputs(
    seed: int, count: int, makers: Sequence[Callable[[random.Random], Any]]
) -> Iterator[Any]:
    """`count` inputs from a generator seeded with `seed`, each from one of `makers` in turn
    chosen at random."""
    rng = random.Random(seed)
    for _ in range(count):
        yield rng.choice(makers)(rng)

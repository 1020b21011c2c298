"""Argument types of the bench scripts: a count or a length that must be positive is refused by
argparse, naming the flag, before anything starts (a negative --duration reached time.sleep
after a swarm had been started, a negative --ticks a child's traceback)."""

from __future__ import annotations

import argparse
import math


def _integer_at_least(text: str, least: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"{text!r} is {what}")
    return value


def positive_int(text: str) -> int:
    """An integer of at least 1."""
    return _integer_at_least(text, 1, "not a count of at least 1")


def non_negative_int(text: str) -> int:
    """An integer of at least 0 (a seed)."""
    return _integer_at_least(text, 0, "negative")


def positive_float(text: str) -> float:
    """A finite number above 0 (seconds, minutes)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number above 0")
    return value

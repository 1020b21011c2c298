"""Radio link model: per-frame delay and loss, shared by the batch simulator and the world.

A frame on a link is lost with probability `loss` (independent Bernoulli), or, when a
Gilbert-Elliott burst model is configured, with the loss probability of the link's current
state (good/bad), the state flipping per frame with the given transition probabilities.
A delivered frame arrives after latency + jitter·U(-1, 1), floored at zero, so the mean delay
is the latency whenever jitter <= latency.  With `range_m` set, links longer than that lose
every frame.  Profiles and the named ones are in swarm_config/radio.py.

Every link may have a profile of its own (`LinkTable`: one value per sender x receiver, as a
network fault sets them, world/faults.py) and may be cut (a partition).  A uniform profile is a
table of scalars, so one function draws both, with the same draws: one uniform number per link
for the loss and one for the delay, and one more for the burst state only when some link has a
burst model.  With no network fault the draws are therefore exactly those of the profile.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from swarm_config.radio import LinkProfile

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class LinkTable:
    """The link profile of each link, sender x receiver: arrays of one shape (N, N), or scalars
    for every link alike.  Burst parameters matter only where `burst` is true, `loss` only where
    it is false; `cut` links lose every frame (a partition)."""

    latency_ms: FloatArray | float
    jitter_ms: FloatArray | float
    loss: FloatArray | float
    burst: BoolArray | bool
    good_to_bad: FloatArray | float
    bad_to_good: FloatArray | float
    loss_in_good: FloatArray | float
    loss_in_bad: FloatArray | float
    cut: BoolArray | bool = False
    range_m: float | None = None
    """One range for the whole medium (a profile's, never per link)."""

    @classmethod
    def from_profile(cls, profile: LinkProfile) -> LinkTable:
        """Every link alike (scalars)."""
        b = profile.burst
        return cls(
            latency_ms=profile.latency_ms,
            jitter_ms=profile.jitter_ms,
            loss=profile.loss,
            burst=b is not None,
            good_to_bad=0.0 if b is None else b.good_to_bad,
            bad_to_good=0.0 if b is None else b.bad_to_good,
            loss_in_good=0.0 if b is None else b.loss_in_good,
            loss_in_bad=0.0 if b is None else b.loss_in_bad,
            range_m=profile.range_m,
        )

    def rows(self, senders: IntArray) -> LinkTable:
        """The links from `senders` (S,) to every robot: array fields of shape (S, N)."""
        picked: dict[str, Any] = {
            f.name: value[senders, :]
            for f in fields(self)
            if isinstance(value := getattr(self, f.name), np.ndarray)
        }
        return replace(self, **picked)


@dataclass(frozen=True)
class LinkDraw:
    delivered: BoolArray
    delay_s: FloatArray
    in_bad_state: BoolArray


def draw_links(
    links: LinkProfile | LinkTable,
    in_bad_state: BoolArray,
    link_length_m: FloatArray | None,
    rng: np.random.Generator,
) -> LinkDraw:
    """Fate of one frame on each link of shape `in_bad_state.shape` (a table's fields broadcast
    against it)."""
    table = LinkTable.from_profile(links) if isinstance(links, LinkProfile) else links
    shape = in_bad_state.shape
    u_loss = rng.random(shape)
    u_delay = rng.random(shape)
    if not np.any(table.burst):
        lost = u_loss < table.loss
        bad = in_bad_state
    else:
        u_state = rng.random(shape)
        flipped = np.where(in_bad_state, u_state >= table.bad_to_good, u_state < table.good_to_bad)
        bad = np.where(table.burst, flipped, in_bad_state)
        in_burst = np.where(bad, table.loss_in_bad, table.loss_in_good)
        lost = u_loss < np.where(table.burst, in_burst, table.loss)
    if table.range_m is not None and link_length_m is not None:
        lost = lost | (link_length_m > table.range_m)
    if np.any(table.cut):
        lost = lost | table.cut
    delay_ms = table.latency_ms + table.jitter_ms * (2.0 * u_delay - 1.0)
    return LinkDraw(delivered=~lost, delay_s=np.maximum(delay_ms, 0.0) / 1000.0, in_bad_state=bad)

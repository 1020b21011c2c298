"""Radio link model: per-frame delay and loss, shared by the batch simulator and the world.

A frame on a link is lost with probability `loss` (independent Bernoulli), or, when a
Gilbert-Elliott burst model is configured, with the loss probability of the link's current
state (good/bad), the state flipping per frame with the given transition probabilities.
A delivered frame arrives after latency + jitter·U(-1, 1), floored at zero, so the mean delay
is the latency whenever jitter <= latency.  With `range_m` set, links longer than that lose
every frame.  Profiles and the named ones are in swarm_config/radio.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from swarm_config.radio import LinkProfile

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class LinkDraw:
    delivered: BoolArray
    delay_s: FloatArray
    in_bad_state: BoolArray


def draw_links(
    profile: LinkProfile,
    in_bad_state: BoolArray,
    link_length_m: FloatArray | None,
    rng: np.random.Generator,
) -> LinkDraw:
    """Fate of one frame on each link of shape `in_bad_state.shape`."""
    shape = in_bad_state.shape
    u_loss = rng.random(shape)
    u_delay = rng.random(shape)
    if profile.burst is None:
        lost = u_loss < profile.loss
        bad = in_bad_state
    else:
        b = profile.burst
        u_state = rng.random(shape)
        bad = np.where(in_bad_state, u_state >= b.bad_to_good, u_state < b.good_to_bad)
        lost = u_loss < np.where(bad, b.loss_in_bad, b.loss_in_good)
    if profile.range_m is not None and link_length_m is not None:
        lost = lost | (link_length_m > profile.range_m)
    delay_ms = profile.latency_ms + profile.jitter_ms * (2.0 * u_delay - 1.0)
    return LinkDraw(delivered=~lost, delay_s=np.maximum(delay_ms, 0.0) / 1000.0, in_bad_state=bad)

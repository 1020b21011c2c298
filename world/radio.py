"""Radio link model: per-frame delay and loss, shared by the batch simulator and the world.

A frame on a link is lost with probability `loss` (independent Bernoulli), or, when a
Gilbert-Elliott burst model is configured, with the loss probability of the link's current
state (good/bad), the state flipping per frame with the given transition probabilities.
A delivered frame arrives after latency + jitter·U(-1, 1), floored at zero, so the mean delay
is the latency whenever jitter <= latency.  With `range_m` set, links longer than that lose
every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class BurstLoss(BaseModel):
    """Gilbert-Elliott two-state loss: per-frame transition and per-state loss probabilities."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    good_to_bad: float = Field(ge=0.0, le=1.0)
    bad_to_good: float = Field(gt=0.0, le=1.0)
    loss_in_good: float = Field(default=0.0, ge=0.0, le=1.0)
    loss_in_bad: float = Field(default=1.0, ge=0.0, le=1.0)

    @property
    def stationary_loss(self) -> float:
        p_bad = self.good_to_bad / (self.good_to_bad + self.bad_to_good)
        return (1.0 - p_bad) * self.loss_in_good + p_bad * self.loss_in_bad


class LinkProfile(BaseModel):
    """How the radio medium treats every link."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    latency_ms: float = Field(default=0.0, ge=0.0, le=10_000.0)
    jitter_ms: float = Field(default=0.0, ge=0.0, le=10_000.0)
    loss: float = Field(default=0.0, ge=0.0, le=1.0)
    burst: BurstLoss | None = None
    range_m: float | None = Field(default=None, gt=0.0)

    @model_validator(mode="after")
    def _one_loss_model(self) -> LinkProfile:
        if self.burst is not None and self.loss > 0.0:
            raise ValueError("give either 'loss' (independent) or 'burst' (Gilbert-Elliott)")
        return self

    @property
    def max_delay_s(self) -> float:
        return (self.latency_ms + self.jitter_ms) / 1000.0


PROFILES: dict[str, LinkProfile] = {
    "ideal": LinkProfile(),
    "lab": LinkProfile(latency_ms=3.0, jitter_ms=2.0, loss=0.01),
    "lossy": LinkProfile(latency_ms=50.0, jitter_ms=20.0, loss=0.2),
    "bursty": LinkProfile(
        latency_ms=20.0,
        jitter_ms=10.0,
        burst=BurstLoss(good_to_bad=0.05, bad_to_good=0.3, loss_in_bad=0.9),
    ),
}
"""Named profiles; scenarios and the running world refer to them by name."""


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

"""Radio link profiles: per-frame latency, jitter and loss, and the named profiles.

The link model that draws each frame's fate from a profile is in world/radio.py: a frame is lost
with probability `loss`, or with the loss probability of the current Gilbert-Elliott state when
`burst` is set; a delivered frame arrives after latency + jitter·U(-1, 1), floored at zero.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class BurstLoss(BaseModel):
    """Gilbert-Elliott two-state loss: per-frame transition and per-state loss probabilities."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
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

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
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

"""Windows and distances that define a run's summary figures (DESIGN.md §8).

The metrics themselves (tracking and formation errors, gaps, collisions, eq. 16's error term)
are computed by world/metrics.py from these settings.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat


class MetricsConfig(BaseModel):
    """Windows and distances that define the summary figures."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    steady_state_start_s: float = Field(default=20.0, ge=0.0)
    fitness_window_start_s: float = Field(default=0.0, ge=0.0)
    """Start of the window of eq. 16's error term; 0 averages over the whole run."""
    nominal_hold_s: float = Field(default=3.0, ge=0.0)
    apf_influence_m: PositiveFloat = 0.4
    body_radius_m: PositiveFloat = 0.3

"""Parameters of the synthesised sensors: the sonar ring and the indoor positioning fix.

The sensor models that use them are in world/sensors.py (DESIGN.md §4).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat

MIN_RATE_HZ = 0.01
"""The lowest sensor, fix or broadcast rate a scenario may give: one per 100 s, longer than a
run needs between two updates.  Slower rates drew periods too long for the simulators' integer
tick and nanosecond counters (1e-17 Hz crashed `swarm sim` and `swarm tune` with an
OverflowError)."""

RATE_DESCRIPTION = (
    f"updates per second, at least {MIN_RATE_HZ:g} Hz (one per {1 / MIN_RATE_HZ:g} s)"
)


class SonarParams(BaseModel):
    """The ultrasound ring (the paper's sonar IPs): cone, range limits, noise, update rate."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    beam_half_width_rad: float = Field(default=float(np.deg2rad(15.0)), gt=0.0, lt=np.pi)
    min_range_m: float = Field(default=0.02, ge=0.0)
    max_range_m: PositiveFloat = 3.0
    noise_std_m: float = Field(default=0.005, ge=0.0)
    rate_hz: float = Field(default=20.0, ge=MIN_RATE_HZ, description=RATE_DESCRIPTION)


POSITIONING_RANGE_M = (2**31 - 1) / 1_000_000
"""The largest coordinate, per axis, that the positioning receiver's fix can hold: X_UM and
Y_UM are signed 32-bit micrometres and saturate beyond it (robot_firmware/fpga/positioning.py).
A scenario keeps its robots, obstacles and reference path inside; beyond it every robot would
localise at the edge while the batch simulator, which reads no register, ran on."""


class PositioningParams(BaseModel):
    """The indoor positioning receiver: fix noise and rate (DESIGN.md §4)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    position_noise_std_m: float = Field(default=0.001, ge=0.0)
    heading_noise_std_rad: float = Field(default=0.002, ge=0.0)
    rate_hz: float = Field(default=20.0, ge=MIN_RATE_HZ, description=RATE_DESCRIPTION)

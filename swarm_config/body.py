"""Physical parameters of the robot body that the world's physics core simulates (world.physics).

The motor, slip and encoder models these numbers feed are described in world/physics.py; the
geometry also seeds the firmware's controller parameters (`Scenario.controller_params`).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt


class BodyParams(BaseModel):
    """The paper's robot (L = 0.25 m, r = 0.0508 m) and the hardware effects modelled."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    wheel_base_m: PositiveFloat = 0.25
    wheel_radius_m: PositiveFloat = 0.0508
    body_radius_m: PositiveFloat = 0.3
    motor_time_constant_s: PositiveFloat = 0.05
    motor_no_load_speed_radps: PositiveFloat = 20.0
    slip_std: float = Field(default=0.02, ge=0.0, le=0.5)
    """Standard deviation of the relative rim slip s."""
    slip_correlation_time_s: PositiveFloat = 0.2
    encoder_counts_per_rev: PositiveInt = 2048
    """Counts per wheel revolution after 4x quadrature decoding."""

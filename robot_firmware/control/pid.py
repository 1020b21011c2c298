"""Redundant PID control law, eq. 14, in discrete time.

The body-rate command is

    u = -K_P·e - K_I·∫e dt - K_D·ė + Ẏ_d        (e = Y - Y_d, θ component wrapped)

and the wheel rim speeds are v = P(θ)·u (eq. 9), i.e. ω = v / r.  Eq. 14/15 of the paper have
Ẏ_e on both sides; in discrete time ė is a first-order filtered backward difference of e
(DESIGN.md §6).  K_P, K_I, K_D are diagonal and given per axis as (..., 3) arrays, so a fuzzy
scheduler can move them every tick.

Two practical parts the paper leaves out are added:
* anti-windup: the integral is clamped per axis and is frozen while the previous command
  saturated the wheels or while an avoidance manoeuvre is under way (`integrate=False`);
* wheel-speed saturation: if any wheel would exceed the limit, all four are scaled by the same
  factor, which keeps the direction of motion and only slows it down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle_rad
from robot_firmware.control.kinematics import wheel_speeds_from_pose_rate

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class PidState:
    """Per-robot memory of the control law; arrays have shape (..., 3) except `saturated`."""

    integral: FloatArray
    previous_error: FloatArray
    error_rate: FloatArray
    saturated: BoolArray
    started: BoolArray

    @staticmethod
    def zeros(batch_shape: tuple[int, ...]) -> PidState:
        z = np.zeros(batch_shape + (3,))
        return PidState(
            integral=z,
            previous_error=z.copy(),
            error_rate=z.copy(),
            saturated=np.zeros(batch_shape, dtype=bool),
            started=np.zeros(batch_shape, dtype=bool),
        )


def tracking_error(pose: FloatArray, desired_pose: FloatArray) -> FloatArray:
    """Eq. 12, Y_e = Y - Y_d, with the heading component wrapped to (-π, π]."""
    e = pose - desired_pose
    e[..., 2] = wrap_angle_rad(e[..., 2])
    return e


def filtered_error_rate(
    state: PidState, error: FloatArray, dt_s: float, filter_time_constant_s: float
) -> FloatArray:
    """ė as a first-order low-pass of the backward difference (zero on the first tick)."""
    raw = (error - state.previous_error) / dt_s
    raw[..., 2] = wrap_angle_rad(error[..., 2] - state.previous_error[..., 2]) / dt_s
    alpha = filter_time_constant_s / (filter_time_constant_s + dt_s)
    rate = alpha * state.error_rate + (1.0 - alpha) * raw
    return np.where(state.started[..., None], rate, 0.0)


def redundant_pid_law(
    state: PidState,
    error: FloatArray,
    error_rate: FloatArray,
    desired_rate: FloatArray,
    theta_rad: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    kd: FloatArray,
    integrate: BoolArray,
    dt_s: float,
    integral_limit: FloatArray,
    wheel_base_m: float,
    wheel_radius_m: float,
    max_wheel_speed_radps: float,
) -> tuple[PidState, FloatArray]:
    """One tick of eq. 14: returns the new state and the wheel speed command (..., 4) in rad/s."""
    hold = state.saturated | ~integrate
    integral = np.where(hold[..., None], state.integral, state.integral + error * dt_s)
    integral = np.clip(integral, -integral_limit, integral_limit)
    command = desired_rate - kp * error - ki * integral - kd * error_rate
    wheel_radps = wheel_speeds_from_pose_rate(command, theta_rad, wheel_base_m) / wheel_radius_m
    peak = np.max(np.abs(wheel_radps), axis=-1)
    scale = np.maximum(peak / max_wheel_speed_radps, 1.0)
    wheel_radps = wheel_radps / scale[..., None]
    new_state = PidState(
        integral=integral,
        previous_error=error,
        error_rate=error_rate,
        saturated=scale > 1.0,
        started=np.ones_like(state.started),
    )
    return new_state, wheel_radps

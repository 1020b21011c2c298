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

`axis_error`, `axis_error_rate` and `pid_law` are the compiled forms (numba) that the control
step's kernel calls; the functions below them are their array forms for any batch shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_firmware.control.angles import wrap_angle
from robot_firmware.control.kernels import njit
from robot_firmware.control.kinematics import rim_speeds
from robot_firmware.control.rows import as_rows, from_rows

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


@njit(cache=True)
def axis_error(pose: FloatArray, desired_pose: FloatArray, error_out: FloatArray) -> None:
    """Eq. 12, Y_e = Y - Y_d, with the heading component wrapped to (-π, π]."""
    error_out[0] = pose[0] - desired_pose[0]
    error_out[1] = pose[1] - desired_pose[1]
    error_out[2] = wrap_angle(pose[2] - desired_pose[2])


@njit(cache=True)
def axis_error_rate(
    error: FloatArray,
    previous_error: FloatArray,
    previous_rate: FloatArray,
    started: bool,
    dt_s: float,
    filter_time_constant_s: float,
    rate_out: FloatArray,
) -> None:
    """ė as a first-order low-pass of the backward difference (zero on the first tick)."""
    alpha = filter_time_constant_s / (filter_time_constant_s + dt_s)
    for k in range(3):
        if k == 2:
            raw = wrap_angle(error[2] - previous_error[2]) / dt_s
        else:
            raw = (error[k] - previous_error[k]) / dt_s
        rate_out[k] = alpha * previous_rate[k] + (1.0 - alpha) * raw if started else 0.0


@njit(cache=True)
def _command(
    k: int,
    desired_rate: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    kd: FloatArray,
    error: FloatArray,
    integral: FloatArray,
    error_rate: FloatArray,
) -> float:
    """Eq. 14 on axis k: u = Ẏ_d - K_P·e - K_I·∫e dt - K_D·ė."""
    return desired_rate[k] - kp[k] * error[k] - ki[k] * integral[k] - kd[k] * error_rate[k]


@njit(cache=True)
def pid_law(
    previous_integral: FloatArray,
    was_saturated: bool,
    error: FloatArray,
    error_rate: FloatArray,
    desired_rate: FloatArray,
    theta_rad: float,
    kp: FloatArray,
    ki: FloatArray,
    kd: FloatArray,
    integrate: bool,
    dt_s: float,
    integral_limit: FloatArray,
    wheel_base_m: float,
    wheel_radius_m: float,
    max_wheel_speed_radps: float,
    integral_out: FloatArray,
    wheel_out: FloatArray,
) -> bool:
    """One tick of eq. 14 for one robot; returns whether the wheels saturated."""
    hold = was_saturated or not integrate
    for k in range(3):
        integral = previous_integral[k] if hold else previous_integral[k] + error[k] * dt_s
        integral_out[k] = min(max(integral, -integral_limit[k]), integral_limit[k])
    rims = rim_speeds(
        _command(0, desired_rate, kp, ki, kd, error, integral_out, error_rate),
        _command(1, desired_rate, kp, ki, kd, error, integral_out, error_rate),
        _command(2, desired_rate, kp, ki, kd, error, integral_out, error_rate),
        theta_rad,
        wheel_base_m,
    )
    peak = 0.0
    for k in range(4):
        wheel_out[k] = rims[k] / wheel_radius_m
        peak = max(peak, abs(wheel_out[k]))
    scale = max(peak / max_wheel_speed_radps, 1.0)
    for k in range(4):
        wheel_out[k] = wheel_out[k] / scale
    return scale > 1.0


@njit(cache=True)
def _error_rows(pose: FloatArray, desired: FloatArray) -> FloatArray:
    out = np.empty((pose.shape[0], 3))
    for i in range(pose.shape[0]):
        axis_error(pose[i], desired[i], out[i])
    return out


@njit(cache=True)
def _error_rate_rows(
    error: FloatArray,
    previous_error: FloatArray,
    previous_rate: FloatArray,
    started: BoolArray,
    dt_s: float,
    filter_time_constant_s: float,
) -> FloatArray:
    out = np.empty((error.shape[0], 3))
    for i in range(error.shape[0]):
        axis_error_rate(
            error[i], previous_error[i], previous_rate[i], started[i], dt_s,
            filter_time_constant_s, out[i],
        )  # fmt: skip
    return out


@njit(cache=True)
def _pid_rows(
    integral: FloatArray,
    saturated: BoolArray,
    error: FloatArray,
    error_rate: FloatArray,
    desired_rate: FloatArray,
    theta: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    kd: FloatArray,
    integrate: BoolArray,
    integral_limit: FloatArray,
    dt_s: float,
    wheel_base_m: float,
    wheel_radius_m: float,
    max_wheel_speed_radps: float,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    n = error.shape[0]
    integral_out = np.empty((n, 3))
    wheel_out = np.empty((n, 4))
    saturated_out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        saturated_out[i] = pid_law(
            integral[i], saturated[i], error[i], error_rate[i], desired_rate[i], theta[i],
            kp[i], ki[i], kd[i], integrate[i], dt_s, integral_limit[i], wheel_base_m,
            wheel_radius_m, max_wheel_speed_radps, integral_out[i], wheel_out[i],
        )  # fmt: skip
    return integral_out, wheel_out, saturated_out


def tracking_error(pose: ArrayLike, desired_pose: ArrayLike) -> FloatArray:
    """Eq. 12, Y_e = Y - Y_d (..., 3), with the heading component wrapped to (-π, π]."""
    batch, (p, d) = as_rows((pose, 1, np.float64), (desired_pose, 1, np.float64))
    return from_rows(_error_rows(p, d), batch)


def filtered_error_rate(
    state: PidState, error: ArrayLike, dt_s: float, filter_time_constant_s: float
) -> FloatArray:
    """ė as a first-order low-pass of the backward difference (zero on the first tick)."""
    batch, rows = as_rows(
        (error, 1, np.float64),
        (state.previous_error, 1, np.float64),
        (state.error_rate, 1, np.float64),
        (state.started, 0, np.bool_),
    )
    arguments: list[Any] = [*rows, float(dt_s), float(filter_time_constant_s)]
    return from_rows(_error_rate_rows(*arguments), batch)


def redundant_pid_law(
    state: PidState,
    error: ArrayLike,
    error_rate: ArrayLike,
    desired_rate: ArrayLike,
    theta_rad: ArrayLike,
    kp: ArrayLike,
    ki: ArrayLike,
    kd: ArrayLike,
    integrate: ArrayLike,
    dt_s: float,
    integral_limit: ArrayLike,
    wheel_base_m: float,
    wheel_radius_m: float,
    max_wheel_speed_radps: float,
) -> tuple[PidState, FloatArray]:
    """One tick of eq. 14: returns the new state and the wheel speed command (..., 4) in rad/s."""
    batch, rows = as_rows(
        (state.integral, 1, np.float64),
        (state.saturated, 0, np.bool_),
        (error, 1, np.float64),
        (error_rate, 1, np.float64),
        (desired_rate, 1, np.float64),
        (theta_rad, 0, np.float64),
        (kp, 1, np.float64),
        (ki, 1, np.float64),
        (kd, 1, np.float64),
        (integrate, 0, np.bool_),
        (integral_limit, 1, np.float64),
    )
    arguments: list[Any] = [
        *rows, float(dt_s), float(wheel_base_m), float(wheel_radius_m),
        float(max_wheel_speed_radps),
    ]  # fmt: skip
    integral, wheel, saturated = _pid_rows(*arguments)
    new_state = PidState(
        integral=from_rows(integral, batch),
        previous_error=from_rows(rows[2].copy(), batch),
        error_rate=from_rows(rows[3].copy(), batch),
        saturated=from_rows(saturated, batch),
        started=np.ones(batch, dtype=bool),
    )
    return new_state, from_rows(wheel, batch)

"""Physics core: omnidirectional bodies driven by four first-order DC motors.

Per wheel, the motor speed obeys τ·ω̇ = ω_ss - ω with ω_ss = d·ω_nl, where the PWM duty d is
saturated to [-1, 1] (the supply voltage bounds it).  For a duty held over a step of length h
the motor response is exact: ω(t) = ω_ss + (ω₀ - ω_ss)·e^(-t/τ).  The ground speed of each rim
is r·ω·(1 + s), where the slip s is an Ornstein-Uhlenbeck process (exactly discretised, so its
statistics do not depend on the step length), held over a step.

The body moves as eq. 11 says for the actual rim speeds.  Its heading rate is a constant plus an
exponential in t, so θ(t) is exact in closed form; the position is the integral of the rotated
body velocity, taken with three-point Gauss-Legendre quadrature on the exact θ(t), whose error
over a 10 ms step is far below that of 1 kHz explicit Euler.  `step_bodies` is therefore an exact
equivalent of a 1 kHz integration for any step length used here, and the world process and the
batch simulator call the same function with their own step.

Body contacts are circles against circles: an overlap is pushed apart along the line of centres
and reported so that collisions can be counted.  All functions are pure; randomness comes from
an injected generator.

The math is compiled (numba): `advance_bodies` steps a range of bodies, `push_apart` one world's
contacts and `encoder_count` reads one wheel's encoder; `step_bodies`, `resolve_contacts` and
`encoder_counts` run them over any batch shape (the world process), and the batch simulator's
compiled tick loop calls them directly (services/sim/ticks.py).  tests/control/oracle.py
states the same steps in numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange, vectorize
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle
from robot_firmware.control.kinematics import body_rate
from robot_firmware.control.rows import as_rows, from_rows
from swarm_config.body import BodyParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

_GAUSS_NODES = (
    0.5 * (1.0 - math.sqrt(0.6)),
    0.5,
    0.5 * (1.0 + math.sqrt(0.6)),
)
_GAUSS_WEIGHTS = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)
PARALLEL_MIN_ROWS = 64
"""Batches of at least this many rows run their kernel on every core (numba prange)."""


@dataclass(frozen=True)
class BodyState:
    """Ground truth of a batch of bodies: pose (..., 3), wheel speed, angle and slip (..., 4)."""

    pose: FloatArray
    wheel_speed_radps: FloatArray
    wheel_angle_rad: FloatArray
    slip: FloatArray

    @staticmethod
    def at_rest(pose: FloatArray) -> BodyState:
        shape = pose.shape[:-1] + (4,)
        return BodyState(
            pose=np.array(pose, dtype=np.float64),
            wheel_speed_radps=np.zeros(shape),
            wheel_angle_rad=np.zeros(shape),
            slip=np.zeros(shape),
        )


@njit(cache=True)
def _rim_speed(
    duty: float, speed_radps: float, slip: float, no_load_radps: float, wheel_radius_m: float
) -> tuple[float, float, float]:
    """One wheel's held target speed, and the constant and decaying parts of its rim speed."""
    target = min(max(duty, -1.0), 1.0) * no_load_radps
    transient = speed_radps - target
    gain = wheel_radius_m * (1.0 + slip)
    return target, gain * target, gain * transient


@njit(cache=True)
def advance_bodies(
    first: int,
    stop: int,
    pose: FloatArray,
    wheel_speed_radps: FloatArray,
    wheel_angle_rad: FloatArray,
    slip: FloatArray,
    duty: FloatArray,
    slip_noise: FloatArray,
    dt_s: float,
    body: tuple[float, float, float, float, float, float],
    pose_out: FloatArray,
    wheel_speed_out: FloatArray,
    wheel_angle_out: FloatArray,
    slip_out: FloatArray,
) -> None:
    """Bodies (rows) first .. stop - 1 over dt_s with their duties held; `body` is
    `body_constants(params)`.  Row r reads slip_noise row r modulo its rows (rows of one world
    repeated for runs that share their noise)."""
    tau, no_load_radps, wheel_radius_m, wheel_base_m, correlation_s, slip_std = body
    decay = math.exp(-dt_s / tau)
    rho = math.exp(-dt_s / correlation_s)
    spread = slip_std * math.sqrt(1.0 - rho * rho)
    noise_rows = slip_noise.shape[0]
    for r in range(first, stop):
        for k in range(4):
            target, _, _ = _rim_speed(
                duty[r, k], wheel_speed_radps[r, k], slip[r, k], no_load_radps, wheel_radius_m
            )
            transient = wheel_speed_radps[r, k] - target
            wheel_speed_out[r, k] = target + transient * decay
            wheel_angle_out[r, k] = (
                wheel_angle_rad[r, k] + target * dt_s + transient * (tau * (1.0 - decay))
            )
        # Rim ground speeds v(t) = r(1+s)·(target + transient·e^(-t/τ)): a constant and a
        # decaying part, each mapped to the body rates of eq. 11 (at θ + π/4 = π/4, unrotated).
        _, s0, f0 = _rim_speed(
            duty[r, 0], wheel_speed_radps[r, 0], slip[r, 0], no_load_radps, wheel_radius_m
        )
        _, s1, f1 = _rim_speed(
            duty[r, 1], wheel_speed_radps[r, 1], slip[r, 1], no_load_radps, wheel_radius_m
        )
        _, s2, f2 = _rim_speed(
            duty[r, 2], wheel_speed_radps[r, 2], slip[r, 2], no_load_radps, wheel_radius_m
        )
        _, s3, f3 = _rim_speed(
            duty[r, 3], wheel_speed_radps[r, 3], slip[r, 3], no_load_radps, wheel_radius_m
        )
        L4 = 4.0 * wheel_base_m
        a_ss = 0.5 * (s2 - s0)
        b_ss = 0.5 * (s3 - s1)
        w_ss = (s0 + s1 + s2 + s3) / L4
        a_tr = 0.5 * (f2 - f0)
        b_tr = 0.5 * (f3 - f1)
        w_tr = (f0 + f1 + f2 + f3) / L4
        theta0 = pose[r, 2]
        dx = 0.0
        dy = 0.0
        for q in range(3):
            t = dt_s * _GAUSS_NODES[q]
            e_t = math.exp(-t / tau)
            theta_t = theta0 + w_ss * t + w_tr * (tau * (1.0 - e_t))
            a_t = a_ss + a_tr * e_t
            b_t = b_ss + b_tr * e_t
            # eq. 11 for half-differences a, b: (-2a, -2b, 2a, 2b) as rim speeds.
            xd, yd, _ = body_rate(-a_t, -b_t, a_t, b_t, theta_t, wheel_base_m)
            weight = dt_s * _GAUSS_WEIGHTS[q]
            dx += weight * xd
            dy += weight * yd
        dtheta = w_ss * dt_s + w_tr * (tau * (1.0 - decay))
        pose_out[r, 0] = pose[r, 0] + dx
        pose_out[r, 1] = pose[r, 1] + dy
        pose_out[r, 2] = wrap_angle(theta0 + dtheta)
        noise = r % noise_rows
        for k in range(4):
            slip_out[r, k] = rho * slip[r, k] + spread * slip_noise[noise, k]


def body_constants(params: BodyParams) -> tuple[float, float, float, float, float, float]:
    """`params` as `advance_bodies` takes them: motor time constant, no-load speed, wheel radius,
    wheel base, slip correlation time and slip std."""
    return (
        float(params.motor_time_constant_s),
        float(params.motor_no_load_speed_radps),
        float(params.wheel_radius_m),
        float(params.wheel_base_m),
        float(params.slip_correlation_time_s),
        float(params.slip_std),
    )


def _make_step_rows(parallel: bool):  # type: ignore[no-untyped-def]
    def step_rows(pose, speed, angle, slip, duty, noise, dt_s, body):  # type: ignore[no-untyped-def]
        n = pose.shape[0]
        pose_out = np.empty((n, 3))
        speed_out = np.empty((n, 4))
        angle_out = np.empty((n, 4))
        slip_out = np.empty((n, 4))
        for i in prange(n):
            advance_bodies(
                i, i + 1, pose, speed, angle, slip, duty, noise, dt_s, body,
                pose_out, speed_out, angle_out, slip_out,
            )  # fmt: skip
        return pose_out, speed_out, angle_out, slip_out

    return njit(cache=True, parallel=parallel)(step_rows)


_step_rows_serial = _make_step_rows(parallel=False)
_step_rows_parallel = _make_step_rows(parallel=True)


def step_bodies(
    state: BodyState,
    duty: FloatArray,
    dt_s: float,
    slip_noise: FloatArray,
    params: BodyParams,
) -> BodyState:
    """Advance the bodies by dt_s with the duty held constant.

    slip_noise: standard normal draws (..., 4) for the slip process (pass zeros for no slip);
    duty and slip_noise broadcast against the bodies' batch shape.
    """
    batch, (pose, speed, angle, slip, held, noise) = as_rows(
        (state.pose, 1, np.float64),
        (state.wheel_speed_radps, 1, np.float64),
        (state.wheel_angle_rad, 1, np.float64),
        (state.slip, 1, np.float64),
        (duty, 1, np.float64),
        (slip_noise, 1, np.float64),
    )
    kernel = _step_rows_parallel if pose.shape[0] >= PARALLEL_MIN_ROWS else _step_rows_serial
    pose_out, speed_out, angle_out, slip_out = kernel(
        pose, speed, angle, slip, held, noise, float(dt_s), body_constants(params)
    )
    return BodyState(
        pose=from_rows(pose_out, batch),
        wheel_speed_radps=from_rows(speed_out, batch),
        wheel_angle_rad=from_rows(angle_out, batch),
        slip=from_rows(slip_out, batch),
    )


def counts_per_radian(counts_per_rev: int) -> float:
    """Encoder counts per radian of wheel angle after 4x decoding."""
    return counts_per_rev / (2.0 * math.pi)


@njit(cache=True)
def encoder_count(wheel_angle_rad: float, counts_per_rad: float) -> int:
    """Quadrature encoder position after 4x decoding: the angle quantised to whole counts."""
    return math.floor(wheel_angle_rad * counts_per_rad)


@vectorize(["int64(float64, float64)"], cache=True)
def _encoder_counts(wheel_angle_rad: float, counts_per_rad: float) -> int:
    return encoder_count(wheel_angle_rad, counts_per_rad)


def encoder_counts(wheel_angle_rad: FloatArray, counts_per_rev: int) -> IntArray:
    """`encoder_count` of every wheel angle (..., 4)."""
    counts = _encoder_counts(
        np.asarray(wheel_angle_rad, dtype=np.float64), counts_per_radian(counts_per_rev)
    )
    return np.asarray(counts, dtype=np.int64)


@dataclass(frozen=True)
class ContactReport:
    """Which pairs touch after a step: robot-robot (..., N, N) and robot-obstacle (..., N, M)."""

    robot_robot: BoolArray
    robot_obstacle: BoolArray


@njit(cache=True)
def push_apart(
    positions_m: FloatArray,
    body_radius_m: float,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
    corrected_out: FloatArray,
    robot_robot_out: BoolArray,
    robot_obstacle_out: BoolArray,
) -> None:
    """One world's contacts: positions (N, 2), obstacles (M, 2) and (M,).

    Each robot is pushed by half the overlap of every robot it touches (from the positions
    before correction), then by the whole overlap of every obstacle it touches.
    """
    n = positions_m.shape[0]
    m = obstacle_radii_m.shape[0]
    for i in range(n):
        push_x = 0.0
        push_y = 0.0
        for j in range(n):
            dx = positions_m[i, 0] - positions_m[j, 0]
            dy = positions_m[i, 1] - positions_m[j, 1]
            dist = math.hypot(dx, dy)
            overlap = 2.0 * body_radius_m - dist
            touching = overlap > 0.0 and i != j
            robot_robot_out[i, j] = touching
            reach = max(dist, 1e-9)
            share = 0.5 * overlap if touching else 0.0
            push_x += share * (dx / reach)
            push_y += share * (dy / reach)
        x = positions_m[i, 0] + push_x
        y = positions_m[i, 1] + push_y
        push_x = 0.0
        push_y = 0.0
        for j in range(m):
            dx = x - obstacle_centres_m[j, 0]
            dy = y - obstacle_centres_m[j, 1]
            dist = math.hypot(dx, dy)
            overlap = body_radius_m + obstacle_radii_m[j] - dist
            touching = overlap > 0.0
            robot_obstacle_out[i, j] = touching
            reach = max(dist, 1e-9)
            share = overlap if touching else 0.0
            push_x += share * (dx / reach)
            push_y += share * (dy / reach)
        corrected_out[i, 0] = x + push_x
        corrected_out[i, 1] = y + push_y


def _make_contact_rows(parallel: bool):  # type: ignore[no-untyped-def]
    def contact_rows(positions, body_radius_m, centres, radii):  # type: ignore[no-untyped-def]
        worlds, n = positions.shape[0], positions.shape[1]
        corrected = np.empty((worlds, n, 2))
        robot_robot = np.empty((worlds, n, n), dtype=np.bool_)
        robot_obstacle = np.empty((worlds, n, radii.shape[0]), dtype=np.bool_)
        for w in prange(worlds):
            push_apart(
                positions[w], body_radius_m, centres, radii,
                corrected[w], robot_robot[w], robot_obstacle[w],
            )  # fmt: skip
        return corrected, robot_robot, robot_obstacle

    return njit(cache=True, parallel=parallel)(contact_rows)


_contact_rows_serial = _make_contact_rows(parallel=False)
_contact_rows_parallel = _make_contact_rows(parallel=True)


@njit(cache=True)
def move_one_world(
    pose: FloatArray,
    wheel_speed_radps: FloatArray,
    wheel_angle_rad: FloatArray,
    slip: FloatArray,
    duty: FloatArray,
    slip_noise: FloatArray,
    dt_s: float,
    body: tuple[float, float, float, float, float, float],
    body_radius_m: float,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, BoolArray]:
    """One world's N bodies (rows) over dt_s with their duties held, then pushed apart: what
    `step_bodies` then `resolve_contacts` give for one world, in one call (the world process
    steps its bodies at every act it takes).  Returns the new pose, wheel speeds, wheel angles
    and slips, and the contacts (N, N + M): robot-robot, then robot-obstacle."""
    n = pose.shape[0]
    m = obstacle_radii_m.shape[0]
    pose_out = np.empty((n, 3))
    speed_out = np.empty((n, 4))
    angle_out = np.empty((n, 4))
    slip_out = np.empty((n, 4))
    advance_bodies(
        0, n, pose, wheel_speed_radps, wheel_angle_rad, slip, duty, slip_noise, dt_s, body,
        pose_out, speed_out, angle_out, slip_out,
    )  # fmt: skip
    positions = np.empty((n, 2))
    for i in range(n):
        positions[i, 0] = pose_out[i, 0]
        positions[i, 1] = pose_out[i, 1]
    corrected = np.empty((n, 2))
    robot_robot = np.empty((n, n), dtype=np.bool_)
    robot_obstacle = np.empty((n, m), dtype=np.bool_)
    push_apart(
        positions, body_radius_m, obstacle_centres_m, obstacle_radii_m, corrected,
        robot_robot, robot_obstacle,
    )  # fmt: skip
    contacts = np.empty((n, n + m), dtype=np.bool_)
    for i in range(n):
        pose_out[i, 0] = corrected[i, 0]
        pose_out[i, 1] = corrected[i, 1]
        for j in range(n):
            contacts[i, j] = robot_robot[i, j]
        for j in range(m):
            contacts[i, n + j] = robot_obstacle[i, j]
    return pose_out, speed_out, angle_out, slip_out, contacts


def resolve_contacts(
    positions_m: FloatArray,
    body_radius_m: float,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
) -> tuple[FloatArray, ContactReport]:
    """Push overlapping bodies apart; positions (..., N, 2), obstacles (M, 2) and (M,).

    Returns the corrected positions and which pairs were in contact before correction.
    """
    batch, (positions,) = as_rows((positions_m, 2, np.float64))
    centres = np.asarray(obstacle_centres_m, dtype=np.float64).reshape(-1, 2)
    radii = np.asarray(obstacle_radii_m, dtype=np.float64).reshape(-1)
    rows = positions.shape[0] * positions.shape[1]
    kernel = _contact_rows_parallel if rows >= PARALLEL_MIN_ROWS else _contact_rows_serial
    corrected, robot_robot, robot_obstacle = kernel(positions, float(body_radius_m), centres, radii)
    return from_rows(corrected, batch), ContactReport(
        robot_robot=from_rows(robot_robot, batch), robot_obstacle=from_rows(robot_obstacle, batch)
    )

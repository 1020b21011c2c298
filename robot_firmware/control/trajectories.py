"""Reference trajectories for the leader: the paper's circle, a lemniscate, a waypoint polyline.

The paper's experiment (§IV-B) uses x_d = R cos(ω t), y_d = R sin(ω t), θ_d = π/2 with
R = 1.5 m and ω = 0.35 rad/s.  Each trajectory returns the desired pose Y_d (..., 3) and its
rate Ẏ_d (..., 3) at the times given, as eq. 14 needs both.  Time is an argument; nothing here
reads a clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def _pose(x: FloatArray, y: FloatArray, theta: FloatArray) -> FloatArray:
    if np.ndim(x) == np.ndim(y) == np.ndim(theta) == 0:  # one time: the firmware's every tick
        return np.array((x, y, theta), dtype=np.float64)
    return np.stack(np.broadcast_arrays(x, y, theta), axis=-1).astype(np.float64)


@dataclass(frozen=True)
class CircleTrajectory:
    """x = cx + R cos(ω t + φ₀), y = cy + R sin(ω t + φ₀), θ constant."""

    radius_m: float = 1.5
    angular_rate_radps: float = 0.35
    centre_m: tuple[float, float] = (0.0, 0.0)
    phase_rad: float = 0.0
    heading_rad: float = np.pi / 2

    def evaluate(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        a = self.angular_rate_radps * t + self.phase_rad
        r, w = self.radius_m, self.angular_rate_radps
        if t.ndim == 0:  # one time, the firmware's every tick: the same arithmetic, unstacked
            cos_a, sin_a = np.cos(a), np.sin(a)
            return (
                np.array(
                    (self.centre_m[0] + r * cos_a, self.centre_m[1] + r * sin_a, self.heading_rad)
                ),
                np.array((-r * w * sin_a, r * w * cos_a, 0.0)),
            )
        pose = _pose(
            self.centre_m[0] + r * np.cos(a),
            self.centre_m[1] + r * np.sin(a),
            np.full_like(t, self.heading_rad),
        )
        rate = _pose(-r * w * np.sin(a), r * w * np.cos(a), np.zeros_like(t))
        return pose, rate


@dataclass(frozen=True)
class LemniscateTrajectory:
    """Lemniscate of Gerono: x = cx + A sin(ω t), y = cy + A sin(ω t) cos(ω t), θ constant."""

    amplitude_m: float = 1.5
    angular_rate_radps: float = 0.25
    centre_m: tuple[float, float] = (0.0, 0.0)
    heading_rad: float = np.pi / 2

    def evaluate(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        w = self.angular_rate_radps
        a = w * t
        amp = self.amplitude_m
        pose = _pose(
            self.centre_m[0] + amp * np.sin(a),
            self.centre_m[1] + 0.5 * amp * np.sin(2 * a),
            np.full_like(t, self.heading_rad),
        )
        rate = _pose(amp * w * np.cos(a), amp * w * np.cos(2 * a), np.zeros_like(t))
        return pose, rate


@dataclass(frozen=True)
class PolylineTrajectory:
    """Constant-speed travel along straight segments between waypoints, θ constant.

    With `closed=True` the path returns to the first waypoint and repeats; otherwise the
    reference stops at the last waypoint.
    """

    waypoints_m: tuple[tuple[float, float], ...] = ((0.0, 0.0), (1.0, 0.0))
    speed_mps: float = 0.3
    closed: bool = True
    heading_rad: float = np.pi / 2
    _cumulative_m: FloatArray = field(init=False, repr=False, compare=False)
    _points: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.waypoints_m, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] != 2:
            raise ValueError("a polyline needs at least two (x, y) waypoints")
        if self.closed:
            pts = np.vstack([pts, pts[:1]])
        seg = np.hypot(*np.diff(pts, axis=0).T)
        if np.any(seg <= 0.0):
            raise ValueError("consecutive waypoints must differ")
        object.__setattr__(self, "_points", pts)
        object.__setattr__(self, "_cumulative_m", np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def length_m(self) -> float:
        return float(self._cumulative_m[-1])

    def evaluate(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        s = self.speed_mps * t
        total = self.length_m
        if self.closed:
            s = np.mod(s, total)
            moving = np.ones_like(s, dtype=bool)
        else:
            moving = s < total
            s = np.minimum(s, total)
        last_segment = len(self._points) - 2
        k = np.clip(np.searchsorted(self._cumulative_m, s, side="right") - 1, 0, last_segment)
        start = self._points[k]
        delta = self._points[k + 1] - start
        seg_len = self._cumulative_m[k + 1] - self._cumulative_m[k]
        frac = (s - self._cumulative_m[k]) / seg_len
        pos = start + frac[..., None] * delta
        direction = delta / seg_len[..., None]
        vel = np.where(moving[..., None], direction * self.speed_mps, 0.0)
        pose = _pose(pos[..., 0], pos[..., 1], np.full_like(t, self.heading_rad))
        rate = _pose(vel[..., 0], vel[..., 1], np.zeros_like(t))
        return pose, rate


Trajectory = CircleTrajectory | LemniscateTrajectory | PolylineTrajectory

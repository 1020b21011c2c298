"""Radio link model: per-frame delay and loss, shared by the batch simulator and the world.

A frame on a link is lost with probability `loss` (independent Bernoulli), or, when a
Gilbert-Elliott burst model is configured, with the loss probability of the link's current
state (good/bad), the state flipping per frame with the given transition probabilities.
A delivered frame arrives after latency + jitter·U(-1, 1), floored at zero, so the mean delay
is the latency whenever jitter <= latency.  With `range_m` set, links longer than that lose
every frame.  Profiles and the named ones are in swarm_config/radio.py.

Every link may have a profile of its own (`LinkTable`: one value per sender x receiver, as a
network fault sets them, world/faults.py) and may be cut (a partition).  A uniform profile is a
table of scalars, so one function draws both, with the same draws: one uniform number per link
for the loss and one for the delay, and one more for the burst state only when some link has a
burst model.  With no network fault the draws are therefore exactly those of the profile.

The math is compiled (numba): `next_link_state` moves one link's burst state and
`link_delivery` decides one frame's fate on one link from its uniform draws; `draw_links`
runs them over any shape of links (the world process), and the batch simulator's compiled tick
loop calls them directly (services/sim/ticks.py).  The draws stay in numpy, in the same order.
tests/world/oracle.py states the same model in numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from swarm_config.radio import LinkProfile

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class LinkTable:
    """The link profile of each link, sender x receiver: arrays of one shape (N, N), or scalars
    for every link alike.  Burst parameters matter only where `burst` is true, `loss` only where
    it is false; `cut` links lose every frame (a partition)."""

    latency_ms: FloatArray | float
    jitter_ms: FloatArray | float
    loss: FloatArray | float
    burst: BoolArray | bool
    good_to_bad: FloatArray | float
    bad_to_good: FloatArray | float
    loss_in_good: FloatArray | float
    loss_in_bad: FloatArray | float
    cut: BoolArray | bool = False
    range_m: float | None = None
    """One range for the whole medium (a profile's, never per link)."""

    @classmethod
    def from_profile(cls, profile: LinkProfile) -> LinkTable:
        """Every link alike (scalars)."""
        b = profile.burst
        return cls(
            latency_ms=profile.latency_ms,
            jitter_ms=profile.jitter_ms,
            loss=profile.loss,
            burst=b is not None,
            good_to_bad=0.0 if b is None else b.good_to_bad,
            bad_to_good=0.0 if b is None else b.bad_to_good,
            loss_in_good=0.0 if b is None else b.loss_in_good,
            loss_in_bad=0.0 if b is None else b.loss_in_bad,
            range_m=profile.range_m,
        )

    @property
    def uniform(self) -> bool:
        """Whether every link has the same profile (every field a scalar)."""
        return not any(isinstance(getattr(self, f.name), np.ndarray) for f in fields(self))

    def rows(self, senders: IntArray) -> LinkTable:
        """The links from `senders` (S,) to every robot: array fields of shape (S, N)."""
        picked: dict[str, Any] = {
            f.name: value[senders, :]
            for f in fields(self)
            if isinstance(value := getattr(self, f.name), np.ndarray)
        }
        return replace(self, **picked)


@dataclass(frozen=True)
class LinkDraw:
    delivered: BoolArray
    delay_s: FloatArray
    in_bad_state: BoolArray


@njit(cache=True)
def next_link_state(
    u_state: float, in_bad_state: bool, burst: bool, good_to_bad: float, bad_to_good: float
) -> bool:
    """A link's Gilbert-Elliott state after one frame: it flips with the transition
    probability of the state it is in (u_state uniform on [0, 1)); no burst model: unchanged."""
    if not burst:
        return in_bad_state
    if in_bad_state:
        return u_state >= bad_to_good
    return u_state < good_to_bad


@njit(cache=True)
def link_delivery(
    u_loss: float,
    u_delay: float,
    in_bad_state: bool,
    burst: bool,
    loss: float,
    loss_in_good: float,
    loss_in_bad: float,
    cut: bool,
    link_length_m: float,
    range_m: float,
    latency_ms: float,
    jitter_ms: float,
) -> tuple[bool, float]:
    """Whether one frame crosses a link (in its new burst state) and its delay in seconds."""
    loss_now = (loss_in_bad if in_bad_state else loss_in_good) if burst else loss
    lost = u_loss < loss_now
    lost = lost or link_length_m > range_m or cut
    delay_ms = latency_ms + jitter_ms * (2.0 * u_delay - 1.0)
    return not lost, max(delay_ms, 0.0) / 1000.0


@njit(cache=True)
def _state_rows(
    u_state: FloatArray,
    in_bad: BoolArray,
    burst: BoolArray,
    good_to_bad: FloatArray,
    bad_to_good: FloatArray,
) -> BoolArray:
    out = np.empty(u_state.shape[0], dtype=np.bool_)
    for i in range(u_state.shape[0]):
        out[i] = next_link_state(u_state[i], in_bad[i], burst[i], good_to_bad[i], bad_to_good[i])
    return out


@njit(cache=True)
def _delivery_rows(
    u_loss: FloatArray,
    u_delay: FloatArray,
    bad: BoolArray,
    burst: BoolArray,
    loss: FloatArray,
    loss_in_good: FloatArray,
    loss_in_bad: FloatArray,
    cut: BoolArray,
    length_m: FloatArray,
    range_m: float,
    latency_ms: FloatArray,
    jitter_ms: FloatArray,
) -> tuple[BoolArray, FloatArray]:
    delivered = np.empty(u_loss.shape[0], dtype=np.bool_)
    delay_s = np.empty(u_loss.shape[0])
    for i in range(u_loss.shape[0]):
        delivered[i], delay_s[i] = link_delivery(
            u_loss[i], u_delay[i], bad[i], burst[i], loss[i], loss_in_good[i], loss_in_bad[i],
            cut[i], length_m[i], range_m, latency_ms[i], jitter_ms[i],
        )  # fmt: skip
    return delivered, delay_s


@njit(cache=True)
def _uniform_rows(
    u_state: FloatArray,
    in_bad: BoolArray,
    u_loss: FloatArray,
    u_delay: FloatArray,
    length_m: FloatArray,
    burst: bool,
    good_to_bad: float,
    bad_to_good: float,
    loss: float,
    loss_in_good: float,
    loss_in_bad: float,
    cut: bool,
    range_m: float,
    latency_ms: float,
    jitter_ms: float,
) -> tuple[BoolArray, FloatArray, BoolArray]:
    """`_state_rows` then `_delivery_rows` for links that all share one profile (scalars)."""
    links = u_loss.shape[0]
    bad = np.empty(links, dtype=np.bool_)
    delivered = np.empty(links, dtype=np.bool_)
    delay_s = np.empty(links)
    for i in range(links):
        bad[i] = next_link_state(u_state[i], in_bad[i], burst, good_to_bad, bad_to_good)
        delivered[i], delay_s[i] = link_delivery(
            u_loss[i], u_delay[i], bad[i], burst, loss, loss_in_good, loss_in_bad, cut,
            length_m[i], range_m, latency_ms, jitter_ms,
        )  # fmt: skip
    return delivered, delay_s, bad


class RowDraw:
    """`draw_links` for the links from one sender to each of N robots when they all share one
    profile with no range: what the world's radio medium does with each frame while no
    network fault is active.  The profile's scalars are taken once, and the uniform numbers
    are the same ones in the same order (loss, delay, then burst state: one call of the
    generator for all of them), so the fates equal `draw_links`' bit for bit
    (tests/world/test_radio.py)."""

    def __init__(self, profile: LinkProfile, robot_count: int) -> None:
        if profile.range_m is not None:
            raise ValueError("a ranged profile needs the links' lengths: use draw_links")
        table = LinkTable.from_profile(profile)
        self.profile = profile
        self.burst = bool(table.burst)
        self._robot_count = robot_count
        self._draw_count = robot_count * (3 if self.burst else 2)
        self._zeros = np.zeros(robot_count)
        self._scalars = (
            self.burst, float(table.good_to_bad), float(table.bad_to_good), float(table.loss),
            float(table.loss_in_good), float(table.loss_in_bad), False, math.inf,
            float(table.latency_ms), float(table.jitter_ms),
        )  # fmt: skip

    def __call__(
        self, in_bad_state: BoolArray, rng: np.random.Generator
    ) -> tuple[BoolArray, FloatArray, BoolArray]:
        """Delivered, delay (s) and new burst state of each link of one row (N,)."""
        n = self._robot_count
        u = rng.random(self._draw_count)
        u_state = u[2 * n :] if self.burst else self._zeros
        return _uniform_rows(
            u_state, in_bad_state, u[:n], u[n : 2 * n], self._zeros, *self._scalars
        )


def _flat(arrays: list[ArrayLike], dtypes: list[type]) -> tuple[tuple[int, ...], list[Any]]:
    """Broadcast `arrays` together; their shape and each one flat, contiguous, of its dtype."""
    full = np.broadcast_arrays(*arrays)
    shape = full[0].shape if full else ()
    flat: list[Any] = [
        np.ascontiguousarray(a, dtype=d).reshape(-1) for a, d in zip(full, dtypes, strict=True)
    ]
    return shape, flat


def draw_links(
    links: LinkProfile | LinkTable,
    in_bad_state: BoolArray,
    link_length_m: FloatArray | None,
    rng: np.random.Generator,
) -> LinkDraw:
    """Fate of one frame on each link of shape `in_bad_state.shape` (a table's fields broadcast
    against it)."""
    table = LinkTable.from_profile(links) if isinstance(links, LinkProfile) else links
    shape = in_bad_state.shape
    u_loss = rng.random(shape)
    u_delay = rng.random(shape)
    u_state = rng.random(shape) if np.any(table.burst) else np.zeros(shape)
    length = 0.0 if link_length_m is None else link_length_m
    range_m = math.inf if table.range_m is None else float(table.range_m)
    if table.uniform and np.shape(length) in ((), shape):
        # One profile for every link (no network fault): no broadcasting needed, which would
        # cost the world's every frame several times the draws themselves.
        delivered, delay_s, bad = _uniform_rows(
            u_state.reshape(-1), np.ascontiguousarray(in_bad_state, dtype=np.bool_).reshape(-1),
            u_loss.reshape(-1), u_delay.reshape(-1),
            np.ascontiguousarray(np.broadcast_to(length, shape), dtype=np.float64).reshape(-1),
            bool(table.burst), float(table.good_to_bad), float(table.bad_to_good),
            float(table.loss), float(table.loss_in_good), float(table.loss_in_bad),
            bool(table.cut), range_m, float(table.latency_ms), float(table.jitter_ms),
        )  # fmt: skip
        return LinkDraw(
            delivered=delivered.reshape(shape),
            delay_s=delay_s.reshape(shape),
            in_bad_state=bad.reshape(shape),
        )
    f8, b1 = np.float64, np.bool_
    state_shape, (u_s, bad_in, burst, good_to_bad, bad_to_good) = _flat(
        [u_state, in_bad_state, table.burst, table.good_to_bad, table.bad_to_good],
        [f8, b1, b1, f8, f8],
    )
    bad = _state_rows(u_s, bad_in, burst, good_to_bad, bad_to_good).reshape(state_shape)
    fate_shape, fate_rows = _flat(
        [
            u_loss,
            u_delay,
            bad,
            table.burst,
            table.loss,
            table.loss_in_good,
            table.loss_in_bad,
            table.cut,
            length,
            table.latency_ms,
            table.jitter_ms,
        ],
        [f8, f8, b1, b1, f8, f8, f8, b1, f8, f8, f8],
    )
    u_l, u_d, bad_rows, burst_rows, loss, good, bad_loss, cut, length_rows, latency, jitter = (
        fate_rows
    )
    delivered, delay_s = _delivery_rows(
        u_l, u_d, bad_rows, burst_rows, loss, good, bad_loss, cut, length_rows, range_m, latency,
        jitter,
    )  # fmt: skip
    return LinkDraw(
        delivered=delivered.reshape(fate_shape),
        delay_s=delay_s.reshape(fate_shape),
        in_bad_state=bad,
    )

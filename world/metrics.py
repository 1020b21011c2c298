"""Run metrics (DESIGN.md §8): one definition for tests, summaries, the dashboard and the tuner.

Per sample, from ground truth:
* leader tracking error: ‖(x, y) - (x_d, y_d)‖ and |θ - θ_d| (wrapped) against the trajectory;
* formation error of follower i: ‖p_i - slot_i‖, the slot placed by eq. 17 from the leader's
  *true* pose; its heading error is against the leader's true heading;
* body-to-body gaps robot-robot and robot-obstacle; a collision is the onset of a contact.

A sample is *nominal* for a robot when its reference point (trajectory point for the leader,
slot for a follower) has stayed farther than ρ₀ + 2·body radius from every obstacle's surface for
the last `nominal_hold_s`.  RMS figures are taken over the steady-state window t >= start and
reported over nominal samples (tracking quality) and over all samples (`_all`).

The fitness of eq. 16 uses the time average of Σ_i (|x_ei| + |y_ei| + |θ_ei|) over its own
window t >= `fitness_window_start_s` (default 0: the whole run, transient included, DESIGN.md §6),
so its value does not depend on the run's length; the RMS figures keep the steady-state window.

Who leads can change during a run (leader failover, robot_firmware/leadership.py): the world
tells the accumulator who acts as leader (`set_leader`), and each sample is taken against that
robot.  Its tracking error counts into the leader figures (`*_lead` accumulators, per robot),
every other robot's error against its slot relative to it into the formation figures; slots are
re-referenced as the firmware does (`slot_of`: a robot keeps its scenario slot, the designated
leader takes the slot the acting leader vacated).  Each change is an event in `events`
(t_s, kind "leader_change", from, to, term).  With no change the figures are those of a fixed
leader.

`MetricsAccumulator` consumes one sample at a time for any batch shape, so a live process and the
batch simulator produce the same numbers from the same code: the sample's math is the compiled
`accumulate_samples` (numba), for a range of worlds, which the accumulator runs over its batch and
the batch simulator's compiled tick loop calls directly (services/sim/ticks.py) on the
accumulator's own arrays.  tests/world/oracle.py states the same update in numpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle, wrap_angle_rad
from robot_firmware.control.formation import follower_slot_in_world, slot_in_world
from swarm_config.metrics import MetricsConfig
from swarm_config.scenario import Scenario

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def _onsets(taken: BoolArray, previous: BoolArray | None, n: int) -> list[tuple[int, int]]:
    """The contacts of one world that began at this sample, as counted in `collisions`: (i, j)
    for robot i touching robot j > i, or obstacle j - n when j >= n."""
    if not taken.any():
        return []
    began = taken if previous is None else taken & ~previous.reshape(taken.shape)
    return [(int(i), int(j)) for i, j in zip(*np.nonzero(began), strict=True) if j >= n or j > i]


@dataclass(frozen=True)
class FormationLayout:
    """Robots (N,) of a run: names, which one leads, and each follower's slot."""

    names: tuple[str, ...]
    leader_index: int
    slot_distance_m: FloatArray
    slot_angle_rad: FloatArray

    @property
    def follower_indices(self) -> tuple[int, ...]:
        return tuple(i for i in range(len(self.names)) if i != self.leader_index)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> FormationLayout:
        """The scenario's robots in its order; slot angles in radians (eq. 17)."""
        distance = [r.slot.distance_m if r.slot else 0.0 for r in scenario.robots]
        angle = [math.radians(r.slot.angle_deg) if r.slot else 0.0 for r in scenario.robots]
        return cls(
            names=scenario.robot_names,
            leader_index=scenario.leader_index,
            slot_distance_m=np.array(distance),
            slot_angle_rad=np.array(angle),
        )


def reference_points(
    true_pose: FloatArray,
    trajectory_pose: FloatArray,
    layout: FormationLayout,
    leader_index: int | None = None,
) -> FloatArray:
    """Each robot's reference pose (..., N, 3): the trajectory for the leader, slots for followers.

    Followers' slots come from the leader's true pose; their reference heading is the leader's.
    leader_index: the acting leader (default the scenario's); with another robot leading, the
    scenario's leader takes the slot it vacated.
    """
    lead = layout.leader_index if leader_index is None else leader_index
    distance_m = layout.slot_distance_m.copy()
    angle_rad = layout.slot_angle_rad.copy()
    if lead != layout.leader_index:
        distance_m[layout.leader_index] = layout.slot_distance_m[lead]
        angle_rad[layout.leader_index] = layout.slot_angle_rad[lead]
    leader = true_pose[..., lead, :]
    slots = follower_slot_in_world(leader[..., None, :], distance_m, angle_rad)
    heading = np.broadcast_to(leader[..., None, 2:3], slots.shape[:-1] + (1,))
    ref = np.concatenate((slots, heading), axis=-1)
    ref[..., lead, :] = trajectory_pose
    return ref


def sample_errors(true_pose: FloatArray, reference: FloatArray) -> FloatArray:
    """Signed errors (..., N, 3): pose minus reference, heading wrapped."""
    e = true_pose - reference
    e[..., 2] = wrap_angle_rad(e[..., 2])
    return e


def obstacle_gaps(
    points_m: FloatArray, obstacle_centres_m: FloatArray, obstacle_radii_m: FloatArray
) -> FloatArray:
    """Distance (..., M) from points (..., 2) to each obstacle's surface."""
    d = points_m[..., None, :] - obstacle_centres_m
    return np.asarray(np.hypot(d[..., 0], d[..., 1]) - obstacle_radii_m, dtype=np.float64)


def robot_gaps(positions_m: FloatArray, body_radius_m: float) -> FloatArray:
    """Body-to-body gaps (..., N, N) with +inf on the diagonal."""
    d = positions_m[..., :, None, :] - positions_m[..., None, :, :]
    gaps = np.hypot(d[..., 0], d[..., 1]) - 2.0 * body_radius_m
    n = positions_m.shape[-2]
    return np.where(np.eye(n, dtype=bool), np.inf, gaps)


MetricsConstants = tuple[float, float, float, float, float]
"""Body radius, the obstacle distance that makes a sample not nominal (ρ₀ + 2·body radius),
steady-state start, nominal hold and fitness window start (s)."""


def metrics_constants(config: MetricsConfig) -> MetricsConstants:
    """`config` as `accumulate_samples` takes it."""
    return (
        float(config.body_radius_m),
        float(config.apf_influence_m + 2.0 * config.body_radius_m),
        float(config.steady_state_start_s),
        float(config.nominal_hold_s),
        float(config.fitness_window_start_s),
    )


@njit(cache=True)
def _pairwise_block(values: FloatArray, start: int, count: int) -> float:
    """numpy's pairwise sum of at most 128 values: eight running sums, then the rest."""
    if count < 8:
        total = 0.0
        for i in range(start, start + count):
            total += values[i]
        return total
    r = np.empty(8)
    for j in range(8):
        r[j] = values[start + j]
    i = 8
    while i < count - count % 8:
        for j in range(8):
            r[j] += values[start + i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < count:
        total += values[start + i]
        i += 1
    return total


@njit(cache=True)
def pairwise_sum(values: FloatArray) -> float:
    """Σ values in numpy's pairwise order (`np.sum` of a contiguous run), so that a compiled sum
    equals numpy's to the last bit: runs longer than 128 split in two halves (the first a
    multiple of 8 long) summed alike.  The halving is unrolled onto a stack (numba cannot
    cache a recursive function)."""
    # Post-order walk of the halving tree: (start, count, halves done) and partial results.
    starts = np.empty(64, dtype=np.int64)
    counts = np.empty(64, dtype=np.int64)
    visited = np.zeros(64, dtype=np.bool_)
    partial = np.empty(64)
    top = 0
    starts[0] = 0
    counts[0] = values.shape[0]
    results = 0
    while top >= 0:
        start, count = starts[top], counts[top]
        if count <= 128:
            partial[results] = _pairwise_block(values, start, count)
            results += 1
            top -= 1
        elif visited[top]:
            partial[results - 2] = partial[results - 2] + partial[results - 1]
            results -= 1
            top -= 1
        else:
            visited[top] = True
            half = count // 2
            half -= half % 8
            starts[top + 1], counts[top + 1], visited[top + 1] = start + half, count - half, False
            starts[top + 2], counts[top + 2], visited[top + 2] = start, half, False
            top += 2
    return partial[0]


@njit(cache=True)
def accumulate_samples(
    first: int,
    stop: int,
    t_s: float,
    true_pose: FloatArray,
    trajectory_pose: FloatArray,
    lead: int,
    slot_distance_m: FloatArray,
    slot_angle_rad: FloatArray,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
    constants: MetricsConstants,
    contacts: BoolArray,
    contacts_known: bool,
    previous: BoolArray,
    previous_known: bool,
    per_robot: tuple,
    per_run: tuple,
    errors_out: FloatArray,
    contacts_out: BoolArray,
    scratch: FloatArray,
) -> None:
    """Add one sample of worlds (runs) first .. stop - 1: true poses (W, N, 3) against the
    trajectory pose (W or 1, 3).

    slot_* (N,) are the slots relative to robot `lead`, the acting leader.  contacts (W, N, N + M)
    as the physics reported them (contacts_known false: derived from the gaps), previous the
    last sample's.  per_robot: the accumulator's (W, N) arrays in `MetricsAccumulator.
    ROBOT_FIELDS` order, per_run its (W,) arrays in `RUN_FIELDS` order; updated in place.
    Writes the errors (W, N, 3) and the contacts taken (W, N, N + M); scratch holds 3N floats.
    """
    body_radius_m, near_limit_m, steady_start_s, hold_s, fitness_start_s = constants
    (last_near_s, sq_pos_nom, sq_head_nom, count_nom, sq_pos_all, sq_head_all, count_all,
     max_pos_nom, max_pos_all, sq_pos_nom_lead, sq_head_nom_lead, count_nom_lead,
     sq_pos_all_lead, sq_head_all_lead, count_all_lead) = per_robot  # fmt: skip
    sum_abs_error, count_fitness, min_robot_gap, min_obstacle_gap, collisions = per_run
    n = true_pose.shape[1]
    for w in range(first, stop):
        pose_w = true_pose[w]
        trajectory_w = trajectory_pose[w if trajectory_pose.shape[0] > 1 else 0]
        errors_w = errors_out[w]
        taken_w = contacts_out[w]
        contacts_w = contacts[w]
        previous_w = previous[w]
        m = obstacle_radii_m.shape[0]
        lx = pose_w[lead, 0]
        ly = pose_w[lead, 1]
        ltheta = pose_w[lead, 2]
        onsets = 0
        for i in range(n):
            # Reference: the trajectory for the leader, the slot of eq. 17 for a follower.
            if i == lead:
                rx, ry, rtheta = trajectory_w[0], trajectory_w[1], trajectory_w[2]
            else:
                rx, ry = slot_in_world(lx, ly, ltheta, slot_distance_m[i], slot_angle_rad[i])
                rtheta = ltheta
            errors_w[i, 0] = pose_w[i, 0] - rx
            errors_w[i, 1] = pose_w[i, 1] - ry
            errors_w[i, 2] = wrap_angle(pose_w[i, 2] - rtheta)
            for j in range(m):
                gap = math.hypot(rx - obstacle_centres_m[j, 0], ry - obstacle_centres_m[j, 1])
                if gap - obstacle_radii_m[j] <= near_limit_m:
                    last_near_s[w, i] = t_s
            # Gaps, contacts and their onsets.
            x = pose_w[i, 0]
            y = pose_w[i, 1]
            for j in range(n):
                gap = math.inf
                if j != i:
                    gap = math.hypot(x - pose_w[j, 0], y - pose_w[j, 1]) - 2.0 * body_radius_m
                min_robot_gap[w] = min(min_robot_gap[w], gap)
                touching = contacts_w[i, j] if contacts_known else gap < 0.0
                taken_w[i, j] = touching
                if touching and j > i and not (previous_known and previous_w[i, j]):
                    onsets += 1
            for j in range(m):
                centre_gap = math.hypot(x - obstacle_centres_m[j, 0], y - obstacle_centres_m[j, 1])
                gap = (centre_gap - obstacle_radii_m[j]) - body_radius_m
                min_obstacle_gap[w] = min(min_obstacle_gap[w], gap)
                touching = contacts_w[i, n + j] if contacts_known else gap < 0.0
                taken_w[i, n + j] = touching
                if touching and not (previous_known and previous_w[i, n + j]):
                    onsets += 1
        collisions[w] += onsets

        if t_s >= steady_start_s:
            for i in range(n):
                nominal = (t_s - last_near_s[w, i]) >= hold_s
                pos_sq = errors_w[i, 0] * errors_w[i, 0] + errors_w[i, 1] * errors_w[i, 1]
                head_sq = errors_w[i, 2] * errors_w[i, 2]
                if i == lead:
                    sq_pos_all_lead[w, i] += pos_sq
                    sq_head_all_lead[w, i] += head_sq
                    count_all_lead[w, i] += 1.0
                    if nominal:
                        sq_pos_nom_lead[w, i] += pos_sq
                        sq_head_nom_lead[w, i] += head_sq
                        count_nom_lead[w, i] += 1.0
                else:
                    sq_pos_all[w, i] += pos_sq
                    sq_head_all[w, i] += head_sq
                    count_all[w, i] += 1.0
                    pos = math.sqrt(pos_sq)
                    max_pos_all[w, i] = max(max_pos_all[w, i], pos)
                    if nominal:
                        sq_pos_nom[w, i] += pos_sq
                        sq_head_nom[w, i] += head_sq
                        count_nom[w, i] += 1.0
                        max_pos_nom[w, i] = max(max_pos_nom[w, i], pos)
        if t_s >= fitness_start_s:
            for i in range(n):
                for a in range(3):
                    scratch[3 * i + a] = abs(errors_w[i, a])
            sum_abs_error[w] += pairwise_sum(scratch)
            count_fitness[w] += 1.0


@njit(cache=True)
def _accumulate_worlds(
    t_s: float,
    true_pose: FloatArray,
    trajectory_pose: FloatArray,
    lead: int,
    slot_distance_m: FloatArray,
    slot_angle_rad: FloatArray,
    obstacle_centres_m: FloatArray,
    obstacle_radii_m: FloatArray,
    constants: MetricsConstants,
    contacts: BoolArray,
    contacts_known: bool,
    previous: BoolArray,
    previous_known: bool,
    per_robot: tuple,
    per_run: tuple,
) -> tuple[FloatArray, BoolArray]:
    worlds, n = true_pose.shape[0], true_pose.shape[1]
    errors = np.empty((worlds, n, 3))
    taken = np.empty((worlds, n, n + obstacle_radii_m.shape[0]), dtype=np.bool_)
    scratch = np.empty(3 * n)
    accumulate_samples(
        0, worlds, t_s, true_pose, trajectory_pose, lead, slot_distance_m, slot_angle_rad,
        obstacle_centres_m, obstacle_radii_m, constants, contacts, contacts_known, previous,
        previous_known, per_robot, per_run, errors, taken, scratch,
    )  # fmt: skip
    return errors, taken


class MetricsAccumulator:
    """Streams samples of a batch of runs (batch shape B, N robots) into summary figures."""

    def __init__(
        self,
        batch_shape: tuple[int, ...],
        layout: FormationLayout,
        obstacle_centres_m: FloatArray,
        obstacle_radii_m: FloatArray,
        config: MetricsConfig,
    ) -> None:
        n = len(layout.names)
        shape = batch_shape + (n,)
        self.layout = layout
        self.config = config
        self.obstacle_centres_m = np.asarray(obstacle_centres_m, dtype=np.float64).reshape(-1, 2)
        self.obstacle_radii_m = np.asarray(obstacle_radii_m, dtype=np.float64).reshape(-1)
        self.last_near_obstacle_s = np.full(shape, -np.inf)
        self.sum_sq_position_nominal = np.zeros(shape)
        self.sum_sq_heading_nominal = np.zeros(shape)
        self.count_nominal = np.zeros(shape)
        self.sum_sq_position_all = np.zeros(shape)
        self.sum_sq_heading_all = np.zeros(shape)
        self.count_all = np.zeros(shape)
        self.max_position_nominal = np.zeros(shape)
        self.max_position_all = np.zeros(shape)
        self.sum_abs_error = np.zeros(batch_shape)
        self.count_fitness = np.zeros(batch_shape)
        self.min_robot_gap_m = np.full(batch_shape, np.inf)
        self.min_obstacle_gap_m = np.full(batch_shape, np.inf)
        self.collisions = np.zeros(batch_shape, dtype=np.int64)
        self.sum_sq_position_nominal_lead = np.zeros(shape)
        self.sum_sq_heading_nominal_lead = np.zeros(shape)
        self.count_nominal_lead = np.zeros(shape)
        self.sum_sq_position_all_lead = np.zeros(shape)
        self.sum_sq_heading_all_lead = np.zeros(shape)
        self.count_all_lead = np.zeros(shape)
        self._previous_contacts: BoolArray | None = None
        self._kernel_arrays: (
            tuple[int, tuple[NDArray[np.generic], ...], tuple[tuple[NDArray[np.generic], ...], ...]]
            | None
        ) = None
        self.last_onsets: list[tuple[int, int]] = []
        """The contacts that began at the last sample, one run only (else empty): (i, j) for
        robot i touching robot j > i, or obstacle j - N when j >= N."""
        self.last_t_s = 0.0
        self.leader_index = layout.leader_index
        self.leader_term = 0
        self.events: list[dict[str, object]] = []

    LEAD_FIELDS = (
        "sum_sq_position_nominal_lead",
        "sum_sq_heading_nominal_lead",
        "count_nominal_lead",
        "sum_sq_position_all_lead",
        "sum_sq_heading_all_lead",
        "count_all_lead",
    )
    """Per robot, the samples taken while it acted as leader (the others: while following)."""

    def set_leader(self, leader_index: int, term: int, t_s: float) -> None:
        """From `t_s` on, robot `leader_index` acts as leader in `term`; a change is an event."""
        if not 0 <= leader_index < len(self.layout.names):
            raise ValueError(f"no robot {leader_index} among {self.layout.names}")
        if leader_index != self.leader_index:
            names = self.layout.names
            self.events.append(
                {
                    "t_s": round(float(t_s), 6),
                    "kind": "leader_change",
                    "from": names[self.leader_index],
                    "to": names[leader_index],
                    "term": int(term),
                }
            )
        self.leader_index = leader_index
        self.leader_term = int(term)

    ARRAY_FIELDS = (
        "last_near_obstacle_s",
        "sum_sq_position_nominal",
        "sum_sq_heading_nominal",
        "count_nominal",
        "sum_sq_position_all",
        "sum_sq_heading_all",
        "count_all",
        "max_position_nominal",
        "max_position_all",
        "sum_abs_error",
        "count_fitness",
        "min_robot_gap_m",
        "min_obstacle_gap_m",
        "collisions",
        *LEAD_FIELDS,
    )
    """The running sums and extremes: with the previous contacts and the last sample's time,
    everything a restarted world needs to carry on (world/checkpoint.py)."""

    def export_state(self) -> dict[str, object]:
        """The accumulators as arrays (copies), for a checkpoint."""
        state: dict[str, object] = {
            name: np.array(getattr(self, name)) for name in self.ARRAY_FIELDS
        }
        state["previous_contacts"] = self._previous_contacts
        state["last_t_s"] = self.last_t_s
        state["leader_index"] = self.leader_index
        state["leader_term"] = self.leader_term
        state["events"] = [dict(event) for event in self.events]
        return state

    def import_state(self, state: Mapping[str, object]) -> None:
        """Carry on from `export_state`; shapes must be those of this accumulator."""
        for name in self.ARRAY_FIELDS:
            value = np.asarray(state[name])
            current = np.asarray(getattr(self, name))
            if value.shape != current.shape:
                raise ValueError(f"metrics {name}: shape {value.shape}, expected {current.shape}")
            setattr(self, name, value.astype(current.dtype))
        contacts = state["previous_contacts"]
        self._previous_contacts = None if contacts is None else np.asarray(contacts, dtype=bool)
        self.last_t_s = float(state["last_t_s"])  # type: ignore[arg-type]
        self.leader_index = int(state.get("leader_index", self.layout.leader_index))  # type: ignore[call-overload]
        self.leader_term = int(state.get("leader_term", 0))  # type: ignore[call-overload]
        events = state.get("events", [])
        self.events = [dict(event) for event in events] if isinstance(events, list) else []

    def update(
        self,
        t_s: float,
        true_pose: FloatArray,
        trajectory_pose: FloatArray,
        contacts: BoolArray | None = None,
    ) -> FloatArray:
        """Add one sample; returns the per-robot errors (..., N, 3) for plotting or logging.

        contacts: (..., N, N + M) which pairs touch now, as reported by the physics; if omitted
        they are derived from the gaps.
        """
        n = len(self.layout.names)
        batch = self.count_all.shape[:-1]
        pose = np.ascontiguousarray(np.broadcast_to(true_pose, batch + (n, 3)), dtype=np.float64)
        worlds = int(np.prod(batch, dtype=np.int64))
        width = n + len(self.obstacle_radii_m)
        trajectory = np.ascontiguousarray(
            np.broadcast_to(trajectory_pose, batch + (3,)), dtype=np.float64
        )
        known = contacts is not None
        previous = self._previous_contacts
        distance_m, angle_rad = self.slots_relative_to(self.leader_index)
        errors, taken = _accumulate_worlds(
            float(t_s), pose.reshape(worlds, n, 3), trajectory.reshape(worlds, 3),
            self.leader_index, distance_m, angle_rad, self.obstacle_centres_m,
            self.obstacle_radii_m, metrics_constants(self.config),
            self._contact_rows(contacts, worlds, width), known,
            self._contact_rows(previous, worlds, width), previous is not None,
            *self.kernel_arrays(worlds),
        )  # fmt: skip
        self.last_onsets = _onsets(taken[0], previous, n) if worlds == 1 else []
        self._previous_contacts = taken.reshape(batch + (n, width))
        self.last_t_s = t_s
        return errors.reshape(batch + (n, 3))

    ROBOT_FIELDS = (
        "last_near_obstacle_s",
        "sum_sq_position_nominal",
        "sum_sq_heading_nominal",
        "count_nominal",
        "sum_sq_position_all",
        "sum_sq_heading_all",
        "count_all",
        "max_position_nominal",
        "max_position_all",
        *LEAD_FIELDS,
    )
    """The per-robot arrays, in the order `accumulate_samples` takes them."""
    RUN_FIELDS = (
        "sum_abs_error",
        "count_fitness",
        "min_robot_gap_m",
        "min_obstacle_gap_m",
        "collisions",
    )
    """The per-run arrays, in the order `accumulate_samples` takes them."""

    def slots_relative_to(self, lead: int) -> tuple[FloatArray, FloatArray]:
        """Slot distances and angles (N,) with robot `lead` leading: the scenario's leader
        takes the slot it vacated (`reference_points`)."""
        layout = self.layout
        distance_m = np.array(layout.slot_distance_m, dtype=np.float64)
        angle_rad = np.array(layout.slot_angle_rad, dtype=np.float64)
        if lead != layout.leader_index:
            distance_m[layout.leader_index] = layout.slot_distance_m[lead]
            angle_rad[layout.leader_index] = layout.slot_angle_rad[lead]
        return distance_m, angle_rad

    def kernel_arrays(self, worlds: int) -> tuple[tuple[NDArray[np.generic], ...], ...]:
        """The per-robot (worlds, N) and per-run (worlds,) arrays as `accumulate_samples` takes
        them: views that it updates in place (made again only when an array was replaced, as
        when a checkpoint is restored)."""
        arrays = tuple(getattr(self, name) for name in self.ROBOT_FIELDS + self.RUN_FIELDS)
        cached = self._kernel_arrays
        if (
            cached is not None
            and cached[0] == worlds
            and all(a is b for a, b in zip(cached[1], arrays, strict=True))
        ):
            return cached[2]
        n = len(self.layout.names)
        views = (
            tuple(self._field_rows(name, (worlds, n)) for name in self.ROBOT_FIELDS),
            tuple(self._field_rows(name, (worlds,)) for name in self.RUN_FIELDS),
        )
        self._kernel_arrays = (
            worlds,
            tuple(getattr(self, name) for name in self.ROBOT_FIELDS + self.RUN_FIELDS),
            views,
        )
        return views

    def samples_taken(self, t_s: float, contacts: BoolArray) -> None:
        """Samples up to t_s were added outside `update` (on `kernel_arrays`), the last one with
        these contacts (..., N, N + M)."""
        self._previous_contacts = np.array(contacts, dtype=bool)
        self.last_t_s = t_s

    def _field_rows(self, name: str, shape: tuple[int, ...]) -> NDArray[np.generic]:
        """The accumulator array `name` as a (worlds, ...) view the kernel updates in place."""
        array = getattr(self, name)
        if not array.flags.c_contiguous or not array.flags.writeable:
            array = np.ascontiguousarray(array).copy()
            setattr(self, name, array)
        view = array.reshape(shape)
        assert np.shares_memory(view, array)
        return view

    @staticmethod
    def _contact_rows(contacts: BoolArray | None, worlds: int, width: int) -> BoolArray:
        if contacts is None:
            return np.zeros((worlds, 0, width), dtype=np.bool_)
        return np.ascontiguousarray(contacts, dtype=np.bool_).reshape(worlds, -1, width)

    def _rms(self, sum_sq: FloatArray, count: FloatArray) -> FloatArray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, np.sqrt(sum_sq / np.maximum(count, 1.0)), np.nan)

    def mean_abs_error_sum(self) -> FloatArray:
        """Time average of Σ_i (|x_ei| + |y_ei| + |θ_ei|) over the fitness window, for eq. 16."""
        count = self.count_fitness
        return np.where(count > 0, self.sum_abs_error / np.maximum(count, 1.0), np.nan)

    def summaries(self) -> list[dict[str, object]]:
        """One summary dict per batch element (flattened batch order)."""
        lead = self.layout.leader_index
        names = self.layout.names
        followers = self.layout.follower_indices
        n = len(names)

        def per_robot(a: FloatArray) -> FloatArray:
            return a.reshape(-1, n)

        def per_run(a: NDArray[np.generic]) -> NDArray[np.generic]:
            return a.reshape(-1)

        pos_nom = per_robot(self._rms(self.sum_sq_position_nominal, self.count_nominal))
        pos_all = per_robot(self._rms(self.sum_sq_position_all, self.count_all))

        def lead_rms(sum_sq: FloatArray, count: FloatArray) -> FloatArray:
            return self._rms(per_robot(sum_sq).sum(axis=-1), per_robot(count).sum(axis=-1))

        lead_pos_nom = lead_rms(self.sum_sq_position_nominal_lead, self.count_nominal_lead)
        lead_pos_all = lead_rms(self.sum_sq_position_all_lead, self.count_all_lead)
        lead_head_nom = lead_rms(self.sum_sq_heading_nominal_lead, self.count_nominal_lead)
        lead_head_all = lead_rms(self.sum_sq_heading_all_lead, self.count_all_lead)
        nominal_count = self.count_nominal + self.count_nominal_lead
        share = per_robot(nominal_count / np.maximum(self.count_all + self.count_all_lead, 1.0))
        followed = per_robot(self.count_all) > 0
        followers = tuple(
            i for i in range(n) if i in self.layout.follower_indices or followed[..., i].any()
        )
        max_nom = per_robot(self.max_position_nominal)
        max_all = per_robot(self.max_position_all)
        robot_gap = per_run(self.min_robot_gap_m)
        obstacle_gap = per_run(self.min_obstacle_gap_m)
        collisions = per_run(self.collisions)
        abs_error = per_run(self.mean_abs_error_sum())
        out: list[dict[str, object]] = []
        for b in range(pos_nom.shape[0]):
            out.append(
                {
                    "leader": names[lead],
                    "leader_tracking_rms_m": _figure(lead_pos_nom[b]),
                    "leader_tracking_rms_all_m": _figure(lead_pos_all[b]),
                    "leader_heading_rms_rad": _figure(lead_head_nom[b]),
                    "leader_heading_rms_all_rad": _figure(lead_head_all[b]),
                    "formation_rms_m": {names[i]: _figure(pos_nom[b, i]) for i in followers},
                    "formation_rms_all_m": {names[i]: _figure(pos_all[b, i]) for i in followers},
                    "formation_max_m": _figure(max((max_nom[b, i] for i in followers), default=0)),
                    "formation_max_all_m": _figure(
                        max((max_all[b, i] for i in followers), default=0)
                    ),
                    "nominal_share": {names[i]: _figure(share[b, i]) for i in range(n)},
                    "min_robot_separation_m": _figure(robot_gap[b]),
                    "min_obstacle_clearance_m": _figure(obstacle_gap[b]),
                    "collisions": int(collisions[b]),
                    "mean_abs_error_sum": _figure(abs_error[b]),
                    "events": [dict(event) for event in self.events],
                }
            )
        return out


def _figure(value: object) -> float | None:
    """A JSON-friendly rounded number; None for NaN or infinity (no samples, no obstacle)."""
    x = float(value)  # type: ignore[arg-type]
    return round(x, 6) if np.isfinite(x) else None


def fitness_snr(
    mean_abs_error_sum: FloatArray | float,
    rule_count_sum: FloatArray | float,
    error_weight: float,
    rule_weight: float,
) -> FloatArray:
    """Eq. 16: -10·log10(w_e·mean Σ_i(|x_e|+|y_e|+|θ_e|) + w_r·Σ_i N_i); larger is better."""
    cost = error_weight * np.asarray(mean_abs_error_sum) + rule_weight * np.asarray(rule_count_sum)
    return np.asarray(-10.0 * np.log10(cost), dtype=np.float64)

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
batch simulator produce the same numbers from the same code.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.angles import wrap_angle_rad
from robot_firmware.control.formation import follower_slot_in_world
from swarm_config.metrics import MetricsConfig
from swarm_config.scenario import Scenario

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


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
        cfg = self.config
        reference = reference_points(true_pose, trajectory_pose, self.layout, self.leader_index)
        errors = sample_errors(true_pose, reference)
        near = obstacle_gaps(reference[..., :2], self.obstacle_centres_m, self.obstacle_radii_m)
        limit = cfg.apf_influence_m + 2.0 * cfg.body_radius_m
        near_any = np.any(near <= limit, axis=-1)
        self.last_near_obstacle_s = np.where(near_any, t_s, self.last_near_obstacle_s)

        rgaps = robot_gaps(true_pose[..., :2], cfg.body_radius_m)
        ogaps = obstacle_gaps(true_pose[..., :2], self.obstacle_centres_m, self.obstacle_radii_m)
        ogaps = ogaps - cfg.body_radius_m
        self.min_robot_gap_m = np.minimum(self.min_robot_gap_m, np.min(rgaps, axis=(-2, -1)))
        if ogaps.shape[-1]:
            self.min_obstacle_gap_m = np.minimum(
                self.min_obstacle_gap_m, np.min(ogaps, axis=(-2, -1))
            )
        if contacts is None:
            contacts = np.concatenate((rgaps < 0.0, ogaps < 0.0), axis=-1)
        previous = self._previous_contacts
        onset = contacts if previous is None else contacts & ~previous
        self._previous_contacts = contacts
        n = len(self.layout.names)
        upper = np.triu(np.ones((n, n), dtype=bool), k=1)
        rr_onsets = np.sum(onset[..., :n] & upper, axis=(-2, -1))
        ro_onsets = np.sum(onset[..., n:], axis=(-2, -1))
        self.collisions += rr_onsets + ro_onsets

        if t_s >= cfg.steady_state_start_s:
            nominal = (t_s - self.last_near_obstacle_s) >= cfg.nominal_hold_s
            pos_sq = errors[..., 0] ** 2 + errors[..., 1] ** 2
            head_sq = errors[..., 2] ** 2
            leads = np.arange(len(self.layout.names)) == self.leader_index
            follows = ~leads
            self.sum_sq_position_all += np.where(follows, pos_sq, 0.0)
            self.sum_sq_heading_all += np.where(follows, head_sq, 0.0)
            self.count_all += follows
            self.sum_sq_position_nominal += np.where(nominal & follows, pos_sq, 0.0)
            self.sum_sq_heading_nominal += np.where(nominal & follows, head_sq, 0.0)
            self.count_nominal += nominal & follows
            self.sum_sq_position_all_lead += np.where(leads, pos_sq, 0.0)
            self.sum_sq_heading_all_lead += np.where(leads, head_sq, 0.0)
            self.count_all_lead += leads
            self.sum_sq_position_nominal_lead += np.where(nominal & leads, pos_sq, 0.0)
            self.sum_sq_heading_nominal_lead += np.where(nominal & leads, head_sq, 0.0)
            self.count_nominal_lead += nominal & leads
            pos = np.where(follows, np.sqrt(pos_sq), 0.0)
            self.max_position_all = np.maximum(self.max_position_all, pos)
            self.max_position_nominal = np.maximum(
                self.max_position_nominal, np.where(nominal, pos, 0.0)
            )
        if t_s >= cfg.fitness_window_start_s:
            self.sum_abs_error += np.sum(np.abs(errors), axis=(-2, -1))
            self.count_fitness += 1.0
        self.last_t_s = t_s
        return errors

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

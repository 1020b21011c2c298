"""Turning truth and telemetry into Rerun records: the dashboard's pure core.

`SwarmScene` holds what the scenario fixes (names, colours, obstacles, the leader's reference
path, the formation layout) and the little state a picture needs (recent poses for the trails,
radio counters for a windowed delivery ratio). Each `on_*` method takes one message and returns
the records to log, stamped with the message's simulated time. Archetypes are only built here,
never logged: nothing opens a socket or reads a clock, so a test can feed hand-made messages.

Run events (swarm_config/faults.py `RunEvent`: faults injected or refused, robots down and up,
leader changes, world resumed) become a line of the event log and a marker on their kind's row
of the fault timeline, at the simulation time the world stamped them with (`on_event`).

Errors are the metrics of DESIGN.md §8 computed with `world.metrics` (`reference_points`,
`sample_errors`): the leader against the trajectory (paper Fig. 12), each follower against its
slot placed by eq. 17 from the leader's *true* pose (Fig. 13).
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, get_args

import numpy as np
import rerun as rr
from pydantic import ValidationError

from robot_firmware.net.messages import TelemetryMessage, TruthMessage
from services.dashboard import entities
from swarm_config.faults import FAULT_ADAPTER, EventKind, NetFault, RunEvent, fault_subjects
from swarm_config.scenario import Scenario
from world.metrics import FormationLayout, reference_points, sample_errors
from world.realtime_guard import RealTimeFactorWindow

Rgb = tuple[int, int, int]

ROBOT_COLOURS: tuple[Rgb, ...] = (
    (213, 94, 0),
    (0, 114, 178),
    (0, 158, 115),
    (204, 121, 167),
    (230, 159, 0),
    (86, 180, 233),
    (240, 228, 66),
)
"""Okabe-Ito colours, distinct for colour-blind readers; robot i gets colour i mod 7."""

DOWN_COLOUR: Rgb = (150, 150, 150)
OBSTACLE_COLOUR: Rgb = (70, 70, 70)
INFLUENCE_COLOUR: Rgb = (185, 185, 185)
REFERENCE_COLOUR: Rgb = (40, 40, 40)
REFERENCE_PATH_COLOUR: Rgb = (200, 200, 200)
RADIO_COLOURS: tuple[Rgb, Rgb] = ((68, 68, 68), (0, 114, 178))

AXES = ("x", "y", "θ")

TELEMETRY_LEAD_MAX_S = 1.0
"""How far past the newest truth sample a telemetry sample may be stamped and still be drawn.
A robot stamps its telemetry with the world's time extrapolated by at most a period, and the
world sends truth every few periods; only a robot whose world is gone or frozen (its clock
runs on in a safe stop) or one that lies about its time stamps further ahead.  Such a sample
would stretch the timeline and, at the next truth sample, look like a world that restarted
(its clock a second or more behind the scene's): so it is not drawn (`ahead_of_world`)."""

EVENT_KINDS: tuple[str, ...] = get_args(EventKind)
EVENT_ROWS: dict[str, int] = {
    kind: len(EVENT_KINDS) - 1 - row for row, kind in enumerate(EVENT_KINDS)
}
"""The row of each kind on the fault timeline, the first kind on top."""


@dataclass(frozen=True)
class EventStyle:
    colour: Rgb
    marker: rr.components.MarkerShape
    level: str
    """The TextLog level of its line."""


EVENT_STYLES: dict[str, EventStyle] = {
    "fault_injected": EventStyle((213, 94, 0), rr.components.MarkerShape.Diamond, "WARN"),
    "fault_refused": EventStyle((120, 120, 120), rr.components.MarkerShape.Cross, "WARN"),
    "robot_down": EventStyle((204, 121, 167), rr.components.MarkerShape.Down, "WARN"),
    "robot_up": EventStyle((0, 158, 115), rr.components.MarkerShape.Up, "INFO"),
    "leader_change": EventStyle((0, 114, 178), rr.components.MarkerShape.Asterisk, "WARN"),
    "world_resumed": EventStyle((230, 159, 0), rr.components.MarkerShape.Square, "INFO"),
    "collision": EventStyle((230, 0, 0), rr.components.MarkerShape.Plus, "ERROR"),
}
_DEFAULT_EVENT_STYLE = EventStyle((40, 40, 40), rr.components.MarkerShape.Circle, "INFO")

# Layers of the map, bottom to top.
_DRAW_INFLUENCE = 1.0
_DRAW_OBSTACLE = 2.0
_DRAW_PATH = 3.0
_DRAW_TRAIL = 4.0
_DRAW_SONAR = 4.5
_DRAW_DESIRED = 5.0
_DRAW_BODY = 6.0
_DRAW_HEADING = 7.0
_DRAW_ESTIMATE = 8.0
_DRAW_REFERENCE = 9.0

MAX_PATH_POINTS = 4000


def describe_fault(data: object) -> str:
    """`pwm_stuck robot2 wheel=0 duty=0.5`: a fault's name, whom it hits and its settings."""
    try:
        fault = FAULT_ADAPTER.validate_python(data)
    except ValidationError:
        return json.dumps(data, sort_keys=True, separators=(",", ":"))
    settings = fault.model_dump(exclude_none=True, exclude={"fault", "process", "robot", "robots"})
    if isinstance(fault, NetFault) and fault.link is not None:
        settings.pop("link")
    parts = [fault.fault, *fault_subjects(fault)]
    parts += [f"{key}={_setting(value)}" for key, value in settings.items()]
    return " ".join(parts)


def _setting(value: object) -> str:
    return (
        json.dumps(value, separators=(",", ":")) if isinstance(value, dict | list) else str(value)
    )


def describe_event(event: RunEvent) -> str:
    """One line for the event log: `fault_injected kill robot1 source=schedule`,
    `robot_down robot2`, `leader_change robot2 from=robot1 term=1`, ..."""
    detail = dict(event.detail)
    words: list[str] = [event.kind]
    if event.kind in ("fault_injected", "fault_refused") and "fault" in detail:
        words.append(describe_fault(detail.pop("fault")))
    named = " ".join(words).split()
    if event.subject is not None and not all(p in named for p in event.subject.split(",")):
        words.append(event.subject)
    words += [f"{key}={_setting(value)}" for key, value in sorted(detail.items())]
    return " ".join(words)


def shade(colour: Rgb, factor: float) -> Rgb:
    """Darker for factor < 1 (towards black), lighter for factor > 1 (towards white)."""
    if factor <= 1.0:
        r, g, b = (round(c * factor) for c in colour)
    else:
        t = min(factor - 1.0, 1.0)
        r, g, b = (round(c + (255 - c) * t) for c in colour)
    return (r, g, b)


@dataclass(frozen=True)
class LogRecord:
    """Archetypes (rr.Points2D, rr.Scalars, ...) logged together on one entity."""

    entity_path: str
    archetypes: tuple[Any, ...]
    static: bool = False


def record(entity_path: str, *archetypes: Any, static: bool = False) -> LogRecord:
    return LogRecord(entity_path, archetypes, static)


@dataclass(frozen=True)
class Update:
    """Records to log at one instant of the simulation timeline (None: static records)."""

    t_s: float | None
    records: list[LogRecord]

    def paths(self) -> set[str]:
        return {r.entity_path for r in self.records}


@dataclass
class _RadioWindow:
    span_s: float
    samples: deque[tuple[float, int, int]] = field(default_factory=deque)

    def ratio(self, t_s: float, delivered: int, frames: int) -> float | None:
        """delivered / frames over the last `span_s` of simulated time; None if no frames."""
        samples = self.samples
        samples.append((t_s, delivered, frames))
        while len(samples) > 1 and samples[1][0] <= t_s - self.span_s:
            samples.popleft()
        t0, delivered0, frames0 = samples[0]
        if t_s <= t0 or frames <= frames0:
            return None
        return (delivered - delivered0) / (frames - frames0)


class SwarmScene:
    def __init__(
        self,
        scenario: Scenario,
        trail_duration_s: float = 10.0,
        trail_spacing_s: float = 0.1,
        trail_period_s: float = 0.25,
        radio_window_s: float = 1.0,
        real_time_factor_window_s: float = 5.0,
    ) -> None:
        self.scenario = scenario
        self.names = scenario.robot_names
        self.layout = FormationLayout.from_scenario(scenario)
        self.leader = self.names[scenario.leader_index]
        self.followers = tuple(self.names[i] for i in self.layout.follower_indices)
        self.colours = {n: ROBOT_COLOURS[i % len(ROBOT_COLOURS)] for i, n in enumerate(self.names)}
        self.body_radius_m = scenario.robot_body.body_radius_m
        self.trail_duration_s = trail_duration_s
        self.trail_spacing_s = trail_spacing_s
        self.trail_period_s = trail_period_s
        self._trails: dict[str, deque[tuple[float, float, float]]] = {
            n: deque() for n in self.names
        }
        self._next_trail_log_s = 0.0
        self._radio = _RadioWindow(radio_window_s)
        self._real_time_factor = RealTimeFactorWindow(real_time_factor_window_s)
        self._last_t_s: float | None = None
        self._truth_t_s: float | None = None
        self.rejected_truth = 0
        self.unknown_robots: set[str] = set()

    @property
    def last_t_s(self) -> float | None:
        """Simulated time of the newest truth or telemetry seen."""
        return self._last_t_s

    def ahead_of_world(self, t_s: float) -> bool:
        """Whether a telemetry sample stamped `t_s` is more than `TELEMETRY_LEAD_MAX_S` past
        the newest truth sample (before the first one there is nothing to judge by)."""
        return self._truth_t_s is not None and t_s > self._truth_t_s + TELEMETRY_LEAD_MAX_S

    # -- geometry fixed by the scenario ----------------------------------------------------

    def reference_path_m(self) -> np.ndarray:
        """The leader's reference positions (K, 2) over the scenario's duration."""
        duration_s = self.scenario.duration_s
        count = int(min(MAX_PATH_POINTS, max(2, duration_s / 0.05 + 1)))
        t_s = np.linspace(0.0, duration_s, count)
        pose, _ = self.scenario.trajectory.build().evaluate(t_s)
        return np.asarray(pose[:, :2], dtype=np.float64)

    def map_bounds_m(self, margin_m: float = 0.3) -> tuple[float, float, float, float]:
        """x_min, x_max, y_min, y_max enclosing the path, the slots around it, the robots'
        start poses and the obstacles."""
        path = self.reference_path_m()
        reach = float(np.max(self.layout.slot_distance_m, initial=0.0)) + self.body_radius_m
        starts = self.scenario.initial_poses()[:, :2]
        centres, radii = self.scenario.obstacle_arrays()
        lows = [path.min(axis=0) - reach, starts.min(axis=0) - self.body_radius_m]
        highs = [path.max(axis=0) + reach, starts.max(axis=0) + self.body_radius_m]
        if len(radii):
            lows.append((centres - radii[:, None]).min(axis=0))
            highs.append((centres + radii[:, None]).max(axis=0))
        low = np.min(lows, axis=0) - margin_m
        high = np.max(highs, axis=0) + margin_m
        return float(low[0]), float(high[0]), float(low[1]), float(high[1])

    def static_update(self) -> Update:
        """The map's fixed layers and the style of every time series."""
        centres, radii = self.scenario.obstacle_arrays()
        influence_m = self.scenario.controller_params().apf_influence_m
        leader_colour = self.colours[self.leader]
        records = [
            record(entities.MAP, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True),
            record(
                entities.REFERENCE_PATH,
                rr.LineStrips2D(
                    [self.reference_path_m()],
                    colors=[REFERENCE_PATH_COLOUR],
                    radii=[0.012],
                    draw_order=_DRAW_PATH,
                ),
                static=True,
            ),
            record(
                entities.LEADER_ERRORS,
                rr.SeriesLines(
                    colors=[leader_colour, shade(leader_colour, 0.55)],
                    names=[f"{self.leader} position (m)", f"{self.leader} heading (rad)"],
                    widths=[2.0, 1.5],
                ),
                static=True,
            ),
            record(
                entities.FORMATION_ERRORS,
                rr.SeriesLines(
                    colors=[self.colours[n] for n in self.followers],
                    names=[f"{n} (m)" for n in self.followers],
                    widths=[2.0] * len(self.followers),
                ),
                static=True,
            ),
            record(
                entities.DELIVERY_RATIO,
                rr.SeriesLines(
                    colors=list(RADIO_COLOURS),
                    names=["since start", "last second"],
                    widths=[2.0, 1.5],
                ),
                static=True,
            ),
            record(
                entities.REAL_TIME_FACTOR,
                rr.SeriesLines(
                    colors=[REFERENCE_COLOUR],
                    names=[f"last {self._real_time_factor.span_s:g} s of wall time"],
                    widths=[2.0],
                ),
                static=True,
            ),
            record(
                entities.LATENCY_CONFIGURED,
                rr.SeriesLines(
                    colors=[shade(RADIO_COLOURS[0], 1.3), shade(RADIO_COLOURS[0], 1.6)],
                    names=["link latency (ms)", "latency + jitter (ms)"],
                ),
                static=True,
            ),
            record(
                entities.LATENCY_MEASURED,
                rr.SeriesLines(
                    colors=[RADIO_COLOURS[1], shade(RADIO_COLOURS[1], 0.6)],
                    names=["p50 (ms)", "p99 (ms)"],
                ),
                static=True,
            ),
        ]
        for kind in EVENT_KINDS:
            style = EVENT_STYLES.get(kind, _DEFAULT_EVENT_STYLE)
            records.append(
                record(
                    entities.event_marker(kind),
                    rr.SeriesPoints(
                        colors=[style.colour],
                        markers=[style.marker],
                        names=[kind.replace("_", " ")],
                        marker_sizes=[6.0],
                    ),
                    static=True,
                )
            )
        if len(radii):
            records += [
                record(
                    entities.OBSTACLES,
                    rr.Points2D(
                        centres, radii=radii, colors=[OBSTACLE_COLOUR], draw_order=_DRAW_OBSTACLE
                    ),
                    static=True,
                ),
                record(
                    entities.OBSTACLE_INFLUENCE,
                    rr.Ellipses2D(
                        centers=centres,
                        half_sizes=np.repeat((radii + influence_m)[:, None], 2, axis=1),
                        colors=[INFLUENCE_COLOUR],
                        line_radii=[0.006],
                        draw_order=_DRAW_INFLUENCE,
                    ),
                    static=True,
                ),
            ]
        for name in self.names:
            colour = self.colours[name]
            for gain in entities.GAIN_NAMES:
                records.append(
                    record(
                        entities.gain(gain, name),
                        rr.SeriesLines(
                            colors=[shade(colour, 0.6), colour, shade(colour, 1.45)],
                            names=[f"{name} {axis}" for axis in AXES],
                        ),
                        static=True,
                    )
                )
        return Update(None, records)

    # -- messages --------------------------------------------------------------------------

    def _restart_if_clock_jumped_back(self, t_s: float) -> None:
        """The world restarted (its clock jumped back): trails and windows start anew."""
        if self._last_t_s is not None and t_s < self._last_t_s - 1.0:
            for trail in self._trails.values():
                trail.clear()
            self._radio = _RadioWindow(self._radio.span_s)
            self._next_trail_log_s = 0.0
            self._last_t_s = t_s

    def _advance_clock(self, t_s: float) -> None:
        self._last_t_s = t_s if self._last_t_s is None else max(self._last_t_s, t_s)

    def on_truth(self, truth: TruthMessage, received_s: float | None = None) -> Update | None:
        """The map, the tracking and formation errors and the radio at truth.t_s; with the
        wall time the message arrived at (`received_s`, monotonic seconds), the real-time
        factor over the last few wall seconds too."""
        missing = [n for n in self.names if n not in truth.robots]
        if missing:
            self.rejected_truth += 1
            return None
        self.unknown_robots.update(set(truth.robots) - set(self.names))
        t_s = truth.t_s
        self._restart_if_clock_jumped_back(t_s)
        self._advance_clock(t_s)
        self._truth_t_s = t_s
        poses = np.array([truth.robots[n].pose for n in self.names], dtype=np.float64)
        reference = reference_points(
            poses, np.asarray(truth.reference, dtype=np.float64), self.layout
        )
        errors = sample_errors(poses, reference)
        position_error_m = np.hypot(errors[:, 0], errors[:, 1])
        lead = self.layout.leader_index

        records: list[LogRecord] = []
        log_trails = t_s >= self._next_trail_log_s
        if log_trails:
            self._next_trail_log_s = t_s + self.trail_period_s
        r = self.body_radius_m
        for i, name in enumerate(self.names):
            x, y, theta = (float(v) for v in poses[i])
            alive = truth.robots[name].alive
            colour = self.colours[name] if alive else DOWN_COLOUR
            layers = [
                rr.Points2D(
                    [[x, y]],
                    radii=[r],
                    colors=[colour],
                    labels=[self._label(name, alive)],
                    show_labels=True,
                    draw_order=_DRAW_BODY,
                ),
                rr.Arrows2D(
                    origins=[[x, y]],
                    vectors=[[1.5 * r * math.cos(theta), 1.5 * r * math.sin(theta)]],
                    colors=[shade(colour, 0.55)],
                    radii=[0.025],
                    draw_order=_DRAW_HEADING,
                ),
                rr.Ellipses2D(
                    centers=[reference[i, :2]],
                    half_sizes=[[r, r]],
                    colors=[colour],
                    line_radii=[0.01],
                    draw_order=_DRAW_DESIRED,
                ),
            ]
            trail = self._trails[name]
            if not trail or t_s - trail[-1][0] >= self.trail_spacing_s - 1e-6:
                trail.append((t_s, x, y))
            while trail and trail[0][0] < t_s - self.trail_duration_s:
                trail.popleft()
            if log_trails:
                points = [(px, py) for _, px, py in trail]
                if points[-1] != (x, y):
                    points.append((x, y))
                layers.append(
                    rr.LineStrips2D(
                        [points],
                        colors=[shade(colour, 1.35)],
                        radii=[0.02],
                        draw_order=_DRAW_TRAIL,
                    )
                )
            records.append(record(entities.robot(name), *layers))
        records += [
            record(
                entities.REFERENCE,
                rr.Points2D(
                    [reference[lead, :2]],
                    radii=[0.035],
                    colors=[REFERENCE_COLOUR],
                    draw_order=_DRAW_REFERENCE,
                ),
            ),
            record(
                entities.LEADER_ERRORS,
                rr.Scalars([float(position_error_m[lead]), abs(float(errors[lead, 2]))]),
            ),
        ]
        if self.followers:
            followers = list(self.layout.follower_indices)
            records.append(
                record(entities.FORMATION_ERRORS, rr.Scalars(position_error_m[followers]))
            )
        records += self._radio_records(truth)
        if received_s is not None:
            factor = self._real_time_factor.add(received_s, t_s)
            if factor is not None:
                records.append(record(entities.REAL_TIME_FACTOR, rr.Scalars([factor])))
        return Update(t_s, records)

    def _label(self, name: str, alive: bool) -> str:
        parts = [name]
        if name == self.leader:
            parts.append("leader")
        if not alive:
            parts.append("down")
        return " · ".join(parts)

    def _radio_records(self, truth: TruthMessage) -> list[LogRecord]:
        radio = truth.radio
        cumulative = math.nan if radio.delivery_ratio is None else radio.delivery_ratio
        recent = self._radio.ratio(truth.t_s, radio.delivered, radio.frames)
        profile = radio.profile
        records = [
            record(
                entities.DELIVERY_RATIO,
                rr.Scalars([cumulative, math.nan if recent is None else recent]),
            ),
            record(
                entities.LATENCY_CONFIGURED,
                rr.Scalars([profile.latency_ms, profile.latency_ms + profile.jitter_ms]),
            ),
        ]
        if radio.latency_p50_ms is not None and radio.latency_p99_ms is not None:
            records.append(
                record(
                    entities.LATENCY_MEASURED,
                    rr.Scalars([radio.latency_p50_ms, radio.latency_p99_ms]),
                )
            )
        return records

    def on_telemetry(self, telemetry: TelemetryMessage) -> Update | None:
        """The robot's own pose estimate, its sonar sweep and its scheduled PID gains at
        telemetry.t_s; None for a robot the scenario does not name and for a sample stamped
        too far ahead of the world (`ahead_of_world`)."""
        name = telemetry.robot
        if name not in self.colours:
            self.unknown_robots.add(name)
            return None
        if self.ahead_of_world(telemetry.t_s):
            return None
        self._advance_clock(telemetry.t_s)
        records: list[LogRecord] = []
        if telemetry.estimate is not None:
            x, y, _ = telemetry.estimate
            records.append(
                record(
                    entities.estimate(name),
                    rr.Points2D(
                        [[x, y]],
                        radii=[0.03],
                        colors=[shade(self.colours[name], 0.45)],
                        draw_order=_DRAW_ESTIMATE,
                    ),
                )
            )
            if telemetry.sonar_echoes_m is not None:
                records.append(self._sonar_record(name, (x, y), telemetry.sonar_echoes_m))
        for gain in entities.GAIN_NAMES:
            values: Sequence[float] | None = getattr(telemetry, gain)
            if values is not None:
                records.append(record(entities.gain(gain, name), rr.Scalars(list(values))))
        return Update(telemetry.t_s, records) if records else None

    def _sonar_record(
        self,
        name: str,
        origin_m: tuple[float, float],
        echoes_m: Sequence[tuple[float, float]],
    ) -> LogRecord:
        """Rays from the robot's estimated position to its echoes; empty layers clear old rays."""
        colour = shade(self.colours[name], 1.25)
        return record(
            entities.sonar(name),
            rr.LineStrips2D(
                [[origin_m, echo] for echo in echoes_m],
                colors=[colour],
                radii=[0.006],
                draw_order=_DRAW_SONAR,
            ),
            rr.Points2D(list(echoes_m), radii=[0.02], colors=[colour], draw_order=_DRAW_SONAR),
        )

    def on_event(self, event: RunEvent) -> Update:
        """A run event of the world: a line of the event log and a marker on its kind's row of
        the fault timeline, at the event's own simulation time."""
        style = EVENT_STYLES.get(event.kind, _DEFAULT_EVENT_STYLE)
        records = [
            record(
                entities.EVENTS,
                rr.TextLog(f"t={event.t_s:.2f} s {describe_event(event)}", level=style.level),
            ),
            record(
                entities.event_marker(event.kind),
                rr.Scalars([float(EVENT_ROWS.get(event.kind, -1))]),
            ),
        ]
        return Update(event.t_s, records)

    def on_liveliness(self, role: str, name: str, alive: bool) -> Update:
        """A process joined or left (its liveliness token); stamped at the newest sim time."""
        who = name if name.startswith(role) else f"{role} {name}"
        text = f"{who} {'joined' if alive else 'left'}"
        return Update(
            self._last_t_s if self._last_t_s is not None else 0.0,
            [record(entities.EVENTS, rr.TextLog(text, level="INFO" if alive else "WARN"))],
        )

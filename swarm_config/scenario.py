"""Scenario files: YAML validated by pydantic; configs/scenarios/paper.yaml is the paper's.

A scenario names the robots (one leader; followers with their formation slot, eq. 17), the
leader's trajectory, the obstacles, initial poses, the robot's physical parameters, the
firmware's control parameters (or a fuzzy parameter file), sensor and radio noise, the seed and
the duration.  `load_scenario` turns every problem into a `ScenarioError` whose message names
the file, the field and the problem.

The scenario is read by the world (what to simulate) and by every robot (its mission, built by
`robot_firmware.firmware.RobotMission.from_scenario`); this module therefore imports only the
configuration models next to it and the pure control math, never `world` or the firmware.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PositiveFloat,
    ValidationError,
    field_validator,
    model_validator,
)

from robot_firmware.control.controller import ControllerParams
from robot_firmware.control.fuzzy import FuzzyRuleBase
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from robot_firmware.control.trajectories import (
    CircleTrajectory,
    LemniscateTrajectory,
    PolylineTrajectory,
    Trajectory,
)
from swarm_config.atomic_files import write_file_atomically
from swarm_config.body import BodyParams
from swarm_config.credentials import SERVICE_IDENTITIES
from swarm_config.faults import (
    PROCESS_ROLES,
    ScheduledFault,
    fault_subjects,
    swarm_fault_problem,
)
from swarm_config.metrics import MetricsConfig
from swarm_config.radio import PROFILES, LinkProfile
from swarm_config.sensors import (
    MIN_RATE_HZ,
    POSITIONING_RANGE_M,
    PositioningParams,
    SonarParams,
)
from swarm_config.settings import (
    DEFAULT_SCENARIO_PATH as DEFAULT_SCENARIO_PATH,  # re-exported: importers know it from here
)
from swarm_config.settings import (
    ScenarioError,
    SettingsError,
    boolean_number_problems,
    describe_problems,
    describe_validation_error,
    parse_yaml,
    read_input_file,
    read_yaml,
)

FloatArray = NDArray[np.float64]

MAX_TICKS = 10_000_000
"""The most control periods a run may last (`duration_s / controller.control_period_s`)."""


class _Strict(BaseModel):
    """Every scenario model: unknown keys refused, and no NaN or infinity (`.nan`, `.inf` in
    YAML) in any number, which would run the whole simulation on NaN without a word."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class CircleSpec(_Strict):
    kind: Literal["circle"]
    radius_m: PositiveFloat = 1.5
    angular_rate_radps: float = 0.35
    centre_m: tuple[float, float] = (0.0, 0.0)
    phase_deg: float = 0.0
    heading_deg: float = 90.0

    def reach_m(self) -> float:
        """The largest |x| or |y| the reference reaches."""
        return max(abs(c) for c in self.centre_m) + self.radius_m

    def build(self) -> Trajectory:
        return CircleTrajectory(
            radius_m=self.radius_m,
            angular_rate_radps=self.angular_rate_radps,
            centre_m=self.centre_m,
            phase_rad=math.radians(self.phase_deg),
            heading_rad=math.radians(self.heading_deg),
        )


class LemniscateSpec(_Strict):
    kind: Literal["lemniscate"]
    amplitude_m: PositiveFloat = 1.5
    angular_rate_radps: float = 0.25
    centre_m: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 90.0

    def reach_m(self) -> float:
        """The largest |x| or |y| the reference reaches (at most the amplitude off centre)."""
        return max(abs(c) for c in self.centre_m) + self.amplitude_m

    def build(self) -> Trajectory:
        return LemniscateTrajectory(
            amplitude_m=self.amplitude_m,
            angular_rate_radps=self.angular_rate_radps,
            centre_m=self.centre_m,
            heading_rad=math.radians(self.heading_deg),
        )


class PolylineSpec(_Strict):
    kind: Literal["polyline"]
    waypoints_m: list[tuple[float, float]] = Field(min_length=2)
    speed_mps: PositiveFloat = 0.3
    closed: bool = True
    heading_deg: float = 90.0

    def reach_m(self) -> float:
        """The largest |x| or |y| the reference reaches: a corner's."""
        return max(max(abs(x), abs(y)) for x, y in self.waypoints_m)

    def build(self) -> Trajectory:
        try:
            return PolylineTrajectory(
                waypoints_m=tuple(self.waypoints_m),
                speed_mps=self.speed_mps,
                closed=self.closed,
                heading_rad=math.radians(self.heading_deg),
            )
        except ValueError as exc:
            raise ScenarioError(f"trajectory.waypoints_m: {exc}") from exc


TrajectorySpec = Annotated[CircleSpec | LemniscateSpec | PolylineSpec, Field(discriminator="kind")]


class PoseSpec(_Strict):
    x_m: float
    y_m: float
    heading_deg: float = 90.0

    def as_array(self) -> FloatArray:
        return np.array([self.x_m, self.y_m, math.radians(self.heading_deg)])


class SlotSpec(_Strict):
    """Eq. 17: the follower's place in the leader's frame (x forward, y to the left)."""

    distance_m: PositiveFloat
    angle_deg: float


class RobotSpec(_Strict):
    name: str | None = Field(default=None, pattern=r"^[a-z][a-z0-9_-]{0,31}$")
    role: Literal["leader", "follower"]
    initial_pose: PoseSpec
    slot: SlotSpec | None = None

    @field_validator("name")
    @classmethod
    def _not_a_service(cls, value: str | None) -> str | None:
        # Before, `swarm sim` took a robot named world, and `swarm credentials` then refused
        # the scenario without naming the robot or the field.
        if value in SERVICE_IDENTITIES:
            raise ValueError(
                f"{value!r} is reserved for a service of the run "
                f"({', '.join(SERVICE_IDENTITIES)}): give the robot another name"
            )
        return value

    @model_validator(mode="after")
    def _slot_for_followers(self) -> RobotSpec:
        if self.role == "follower" and self.slot is None:
            raise ValueError("a follower needs a 'slot' (distance_m, angle_deg)")
        if self.role == "leader" and self.slot is not None:
            raise ValueError("the leader has no 'slot'")
        return self


class ObstacleSpec(_Strict):
    position_m: tuple[float, float]
    radius_m: PositiveFloat


class SensorsSpec(_Strict):
    sonar: SonarParams = SonarParams()
    positioning: PositioningParams = PositioningParams()


class RadioSpec(_Strict):
    profile: str | LinkProfile = "ideal"
    """A named profile (ideal, lab, lossy, bursty) or an inline link profile."""
    broadcast_rate_hz: float = Field(
        default=20.0,
        ge=MIN_RATE_HZ,
        description=f"state broadcasts per second per robot, at least {MIN_RATE_HZ:g} Hz and at "
        "most the control rate",
    )

    @model_validator(mode="after")
    def _known_profile(self) -> RadioSpec:
        if isinstance(self.profile, str) and self.profile not in PROFILES:
            raise ValueError(
                f"unknown radio profile {self.profile!r}; known: {', '.join(sorted(PROFILES))}"
            )
        return self

    @property
    def link(self) -> LinkProfile:
        return PROFILES[self.profile] if isinstance(self.profile, str) else self.profile


class FitnessSpec(_Strict):
    """Weights of eq. 16."""

    error_weight: PositiveFloat = 1.0
    rule_weight: float = Field(default=1e-4, ge=0.0)


class Scenario(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    seed: int = Field(default=0, ge=0)
    duration_s: PositiveFloat = 60.0
    trajectory: TrajectorySpec
    robots: list[RobotSpec] = Field(min_length=1)
    obstacles: list[ObstacleSpec] = Field(default_factory=list)
    robot_body: BodyParams = BodyParams()
    controller: ControllerParams = ControllerParams()
    fuzzy_parameter_file: Path | None = None
    sensors: SensorsSpec = SensorsSpec()
    radio: RadioSpec = RadioSpec()
    metrics: MetricsConfig = MetricsConfig()
    fitness: FitnessSpec = FitnessSpec()
    faults: list[ScheduledFault] = Field(default_factory=list)
    """A fault campaign: what to inject at which simulation time (swarm_config/faults.py)."""

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        leaders = [i for i, r in enumerate(self.robots) if r.role == "leader"]
        if len(leaders) != 1:
            raise ValueError(f"exactly one robot must be the leader, found {len(leaders)}")
        names = self.robot_names
        if len(set(names)) != len(names):
            raise ValueError(f"robot names must be unique, got {list(names)}")
        radius = self.robot_body.body_radius_m
        poses = [r.initial_pose for r in self.robots]
        for i, a in enumerate(poses):
            for j in range(i + 1, len(poses)):
                b = poses[j]
                if math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) < 2 * radius:
                    raise ValueError(f"robots {names[i]} and {names[j]} start overlapping")
            for k, obstacle in enumerate(self.obstacles):
                gap = math.hypot(a.x_m - obstacle.position_m[0], a.y_m - obstacle.position_m[1])
                if gap < radius + obstacle.radius_m:
                    raise ValueError(f"robot {names[i]} starts inside obstacle {k}")
        self._inside_the_positioning_range()
        control_rate_hz = 1.0 / self.controller.control_period_s
        if self.radio.broadcast_rate_hz > control_rate_hz:
            raise ValueError(
                f"radio.broadcast_rate_hz ({self.radio.broadcast_rate_hz:g}) is above the control "
                f"rate ({control_rate_hz:g} Hz): a robot broadcasts at most once per control period"
            )
        ticks = self.duration_s / self.controller.control_period_s
        if ticks < 1.0:
            raise ValueError(
                f"duration_s ({self.duration_s:g} s) is shorter than one control period "
                f"({self.controller.control_period_s:g} s): nothing would run"
            )
        if ticks > MAX_TICKS:
            raise ValueError("duration_s / control_period_s is over ten million ticks")
        known = set(names) | set(PROCESS_ROLES)
        for k, entry in enumerate(self.faults):
            unknown = [s for s in fault_subjects(entry.fault) if s not in known]
            if unknown:
                raise ValueError(f"faults[{k}] names {unknown[0]!r}, which is not in this swarm")
            problem = swarm_fault_problem(entry.fault, names)
            if problem is not None:
                raise ValueError(f"faults[{k}]: {problem}")
            if entry.at_s > self.duration_s:
                raise ValueError(f"faults[{k}] is at {entry.at_s} s, after the run ends")
        return self

    def _inside_the_positioning_range(self) -> None:
        """Every start, obstacle and slot along the reference path within the positioning
        receiver's range (`POSITIONING_RANGE_M` per axis); ValueError naming the first one
        beyond it."""
        limit = POSITIONING_RANGE_M
        beyond = f"beyond the positioning receiver's range (|x|, |y| <= {limit:.0f} m)"
        for robot, name in zip(self.robots, self.robot_names, strict=True):
            pose = robot.initial_pose
            if max(abs(pose.x_m), abs(pose.y_m)) > limit:
                raise ValueError(f"robot {name} starts at ({pose.x_m:g}, {pose.y_m:g}) m, {beyond}")
        for k, obstacle in enumerate(self.obstacles):
            reach = max(abs(c) for c in obstacle.position_m) + obstacle.radius_m
            if reach > limit:
                raise ValueError(f"obstacle {k} reaches {reach:g} m, {beyond}")
        slots = [r.slot.distance_m for r in self.robots if r.slot is not None]
        reach = self.trajectory.reach_m() + max(slots, default=0.0)
        if reach > limit:
            raise ValueError(
                f"the trajectory, with the farthest slot around it, reaches {reach:g} m, {beyond}"
            )

    @property
    def robot_names(self) -> tuple[str, ...]:
        return tuple(r.name or f"robot{i + 1}" for i, r in enumerate(self.robots))

    @property
    def leader_index(self) -> int:
        return next(i for i, r in enumerate(self.robots) if r.role == "leader")

    def initial_poses(self) -> FloatArray:
        return np.stack([r.initial_pose.as_array() for r in self.robots])

    def obstacle_arrays(self) -> tuple[FloatArray, FloatArray]:
        centres = np.array([o.position_m for o in self.obstacles], dtype=np.float64).reshape(-1, 2)
        radii = np.array([o.radius_m for o in self.obstacles], dtype=np.float64)
        return centres, radii

    def controller_params(self) -> ControllerParams:
        """The firmware's parameters; geometry the scenario did not set follows the body."""
        body = self.robot_body
        geometry = {
            "wheel_base_m": body.wheel_base_m,
            "wheel_radius_m": body.wheel_radius_m,
            "body_radius_m": body.body_radius_m,
            "encoder_counts_per_rev": body.encoder_counts_per_rev,
            "motor_no_load_speed_radps": body.motor_no_load_speed_radps,
        }
        unset = {k: v for k, v in geometry.items() if k not in self.controller.model_fields_set}
        return self.controller.model_copy(update=unset)

    def metrics_config(self) -> MetricsConfig:
        """Metrics windows from the scenario, distances from the controller and the body."""
        update = {
            "apf_influence_m": self.controller.apf_influence_m,
            "body_radius_m": self.robot_body.body_radius_m,
        }
        unset = {k: v for k, v in update.items() if k not in self.metrics.model_fields_set}
        return self.metrics.model_copy(update=unset)


def parse_scenario(data: object, source: str = "<scenario>") -> Scenario:
    """Validate an already-parsed mapping; problems raise ScenarioError."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: a scenario must be a YAML mapping at the top level")
    booleans = boolean_number_problems(Scenario, data)
    if booleans:
        raise ScenarioError(describe_problems(f"{source}: invalid scenario", booleans))
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(describe_validation_error(f"{source}: invalid scenario", exc)) from None


def load_scenario(path: Path) -> Scenario:
    """Read and validate a scenario file; relative fuzzy parameter paths resolve next to it."""
    try:
        data = read_yaml(path, "scenario file")
    except SettingsError as exc:
        raise ScenarioError(str(exc)) from None
    scenario = parse_scenario(data, str(path))
    fuzzy_file = scenario.fuzzy_parameter_file
    if fuzzy_file is not None and not fuzzy_file.is_absolute():
        resolved = (path.parent / fuzzy_file).resolve()
        scenario = scenario.model_copy(update={"fuzzy_parameter_file": resolved})
    return scenario


RUN_SCENARIO_FILE = "scenario.yaml"
"""A run's own copy of its scenario, in its run folder (`snapshot_scenario`)."""
RUN_FUZZY_PARAMETER_FILE = "fuzzy_parameters.yaml"
"""A run's own copy of the fuzzy parameter file its scenario names, beside its scenario copy."""


def snapshot_scenario(source: Path, folder: Path) -> Path:
    """Copy the scenario file `source`, and the fuzzy parameter file it names, into `folder` as
    the run's own (`scenario.yaml`, `fuzzy_parameters.yaml`); returns the copy's path.

    Every process of a run, and every restart of one, reads the copy: a scenario file edited or
    removed while the run goes on changes nothing in it (before, a world or robot restarted
    mid-run read the edited file and ran another scenario than the processes around it).  The
    scenario is copied byte for byte, comments included; one that names a fuzzy parameter file
    is written again with that key pointing at the copy.  ScenarioError when `source` (or its
    fuzzy parameter file) cannot be read or is not a scenario; FileWriteError when a copy
    cannot be written."""
    try:
        raw = read_input_file(source, "scenario file")
        data = parse_yaml(raw.decode("utf-8"))
    except SettingsError as exc:
        raise ScenarioError(str(exc)) from None
    except (yaml.YAMLError, ValueError, RecursionError) as exc:  # as load_scenario refuses it
        raise ScenarioError(f"{source}: not a scenario file ({exc})") from None
    scenario = parse_scenario(data, str(source))
    copy = folder / RUN_SCENARIO_FILE
    fuzzy_file = scenario.fuzzy_parameter_file
    if fuzzy_file is None:
        write_file_atomically(copy, raw)
        return copy
    assert isinstance(data, dict)  # parse_scenario took it
    try:
        fuzzy_raw = read_input_file(source.parent / fuzzy_file, "fuzzy parameter file")
    except SettingsError as exc:
        raise ScenarioError(f"fuzzy_parameter_file: {exc}") from None
    write_file_atomically(folder / RUN_FUZZY_PARAMETER_FILE, fuzzy_raw)
    data["fuzzy_parameter_file"] = RUN_FUZZY_PARAMETER_FILE
    write_file_atomically(copy, yaml.safe_dump(data, sort_keys=False).encode("utf-8"))
    return copy


def load_fuzzy_parameters(path: Path) -> FuzzyParameters:
    """Read and validate a fuzzy parameter file (YAML or JSON); problems raise ScenarioError."""
    try:
        data = read_yaml(path, "fuzzy parameter file")
        booleans = boolean_number_problems(FuzzyParameters, data)
        if booleans:
            raise ScenarioError(describe_problems(f"{path}: invalid fuzzy parameters", booleans))
        return FuzzyParameters.model_validate(data)
    except SettingsError as exc:
        raise ScenarioError(f"fuzzy_parameter_file: {exc}") from None
    except ValidationError as exc:
        raise ScenarioError(
            describe_validation_error(f"{path}: invalid fuzzy parameters", exc)
        ) from None


def load_rule_base(scenario: Scenario) -> FuzzyRuleBase:
    """The scenario's fuzzy scheduler: its parameter file, or Table 2 with even centres."""
    if scenario.fuzzy_parameter_file is None:
        return FuzzyParameters.table2_defaults().rule_base()
    return load_fuzzy_parameters(scenario.fuzzy_parameter_file).rule_base()

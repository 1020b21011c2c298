"""Scenario files for formations of any size: wedge, line abreast or grid behind one leader.

`generate_scenario_text` writes an ordinary scenario file (the format of `swarm_config.scenario`)
for N robots; `swarm scenario generate` (services/scenario/cli.py) puts it on disk.  The file is
parsed back by `parse_scenario` and checked against the rules below before anyone sees it, so a
generated file is a valid scenario whose formation is collision-free at rest.

Slots (eq. 17: distance L_DL and angle θ_DL in the leader's frame, x forward, y to the left):

* wedge: followers alternate left and right on two arms at ±150° (the paper's triangle is the
  wedge of 3); follower k sits k//2 + 1 spacings down its arm;
* line: followers abreast at ±90°, alternating left and right;
* grid: rows behind the leader, ceil(√N) columns, the leader in the middle of the front row.

The rules (DESIGN.md §6 on eqs. 22-25: ρ is the gap between bodies):

* **At rest nobody pushes.** Every two slots are at least `min_slot_spacing_m` = 2 body radii +
  the APF influence distance ρ₀ apart, centre to centre, so the body gap at the slots is at
  least ρ₀ and the repulsion of eq. 25 is zero there: each follower's slot is a place it can
  reach and stay.  The default spacing adds `SPACING_MARGIN_M` for tracking errors (1.2 m, the
  paper's triangle).  Obstacles keep the same gap from every slot at t = 0.
* **Nobody starts overlapping.** Initial poses are the slots at t = 0 moved 0.3-0.6 spacings in
  a random direction (like the paper's scenario: everyone starts away from the formation), at
  least 2 body radii + `START_MARGIN_M` apart and as far from obstacles.

The leader's path is the paper's circle (1.5 m, 0.525 m/s), a lemniscate or a closed square,
its size raised to the formation's extent (its farthest slot) so the formation fits, at the
same speed.  Obstacles sit 5 cm outside the path (as in the paper's scenario), the first a third
of the way round, the others spread over the next half lap.  Randomness comes from
`random.Random(seed)`, so equal requests give byte-identical files.
"""

from __future__ import annotations

import json
import math
import random
import re
from collections.abc import Sequence
from dataclasses import dataclass
from decimal import Decimal
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.controller import ControllerParams
from robot_firmware.control.formation import follower_slot_in_world
from robot_firmware.control.trajectories import PolylineTrajectory
from swarm_config.body import BodyParams
from swarm_config.scenario import (
    MAX_TICKS,
    PolylineSpec,
    Scenario,
    ScenarioError,
    TrajectorySpec,
    parse_scenario,
)
from swarm_config.settings import parse_yaml

FloatArray = NDArray[np.float64]
Formation = Literal["wedge", "line", "grid"]
TrajectoryKind = Literal["circle", "lemniscate", "polyline"]
FORMATIONS: tuple[str, ...] = get_args(Formation)
TRAJECTORIES: tuple[str, ...] = get_args(TrajectoryKind)

MAX_ROBOTS = 256
SPACING_MARGIN_M = 0.2
"""Added to `min_slot_spacing_m` for the default spacing: room for tracking errors."""
START_MARGIN_M = 0.1
"""Body gap kept between initial poses, and between an initial pose and an obstacle."""
START_OFFSET_SPACINGS = (0.3, 0.6)
"""How far an initial pose lies from its slot at t = 0, in spacings (uniform)."""
START_HEADING_SPREAD_DEG = 30.0
"""Initial headings are 90° ± this (uniform)."""
OBSTACLE_RADIUS_M = 0.15
OBSTACLE_OFFSET_M = 0.05
"""An obstacle's centre lies this far outside the leader's path (the paper's: 1.55 m vs 1.5 m)."""
OBSTACLE_PATH_STEPS = 720
"""Points per lap tried for an obstacle."""
PLACEMENT_ATTEMPTS = 1000
RADIO_PROFILE = "lab"
SCENARIO_NAME_PATTERN = r"[A-Za-z0-9_.-]{1,64}"
"""`Scenario.name`'s pattern."""
WEDGE_ARM_DEG = 150.0
LINE_ARM_DEG = 90.0


@dataclass(frozen=True)
class TrajectoryDefaults:
    size_m: float
    """Circle radius, lemniscate amplitude, or half the side of the square."""
    speed_mps: float
    """Path speed (the lemniscate's peak speed)."""


TRAJECTORY_DEFAULTS: dict[str, TrajectoryDefaults] = {
    "circle": TrajectoryDefaults(size_m=1.5, speed_mps=1.5 * 0.35),  # the paper's circle
    "lemniscate": TrajectoryDefaults(size_m=1.6, speed_mps=1.5 * 0.35),
    "polyline": TrajectoryDefaults(size_m=1.5, speed_mps=0.3),  # configs/.../square-patrol.yaml
}


class ScenarioGenerationError(ScenarioError, ValueError):
    """A request the generator cannot turn into a scenario; the message is meant for the user."""


@dataclass(frozen=True)
class GenerateRequest:
    """What to generate; None means the documented default."""

    robots: int
    formation: str = "wedge"
    spacing_m: float | None = None
    trajectory: str = "circle"
    size_m: float | None = None
    speed_mps: float | None = None
    obstacles: int = 1
    seed: int = 0
    duration_s: float = 60.0
    name: str | None = None


def min_slot_spacing_m(body_radius_m: float, apf_influence_m: float) -> float:
    """Centre distance at which two bodies are ρ₀ apart: below it they repel (eq. 25)."""
    return 2.0 * body_radius_m + apf_influence_m


def default_spacing_m(body_radius_m: float, apf_influence_m: float) -> float:
    return min_slot_spacing_m(body_radius_m, apf_influence_m) + SPACING_MARGIN_M


def formation_slots(formation: str, followers: int, spacing_m: float) -> list[tuple[float, float]]:
    """Each follower's slot as (L_DL in m, θ_DL in degrees), eq. 17, in follower order."""
    if formation in ("wedge", "line"):
        arm_deg = WEDGE_ARM_DEG if formation == "wedge" else LINE_ARM_DEG
        return [
            ((k // 2 + 1) * spacing_m, arm_deg if k % 2 == 0 else -arm_deg)
            for k in range(followers)
        ]
    if formation == "grid":
        columns = math.ceil(math.sqrt(followers + 1))
        leader_column = (columns - 1) // 2
        cells = sorted(
            (
                (row, abs(col - leader_column), col)
                for row in range(followers + 1)
                for col in range(columns)
                if (row, col) != (0, leader_column)
            ),
        )[:followers]
        slots = []
        for row, _, col in cells:
            x_m, y_m = -row * spacing_m, (leader_column - col) * spacing_m
            slots.append((math.hypot(x_m, y_m), math.degrees(math.atan2(y_m, x_m))))
        return slots
    raise ScenarioGenerationError(
        f"unknown formation {formation!r}; known: {', '.join(FORMATIONS)}"
    )


def slot_positions_m(scenario: Scenario, t_s: float = 0.0) -> FloatArray:
    """Where every robot's reference is at t: the leader's on its path, each follower's slot
    placed from it (eq. 17), shape (N, 2), in the scenario's robot order."""
    reference, _ = scenario.trajectory.build().evaluate(t_s)
    leader_pose = np.asarray(reference, dtype=np.float64)
    out = np.empty((len(scenario.robots), 2))
    for i, robot in enumerate(scenario.robots):
        if robot.slot is None:
            out[i] = leader_pose[:2]
        else:
            out[i] = follower_slot_in_world(
                leader_pose, robot.slot.distance_m, math.radians(robot.slot.angle_deg)
            )
    return out


def closest_pair_m(points: FloatArray) -> float:
    """Smallest centre distance between two of the points (inf for fewer than two)."""
    if len(points) < 2:
        return math.inf
    gaps = np.hypot(*(points[:, None, :] - points[None, :, :]).transpose(2, 0, 1))
    return float(np.min(gaps[np.triu_indices(len(points), k=1)]))


def generation_problems(scenario: Scenario) -> list[str]:
    """The rules of this module that a scenario breaks (empty: none)."""
    body_m = scenario.robot_body.body_radius_m
    influence_m = scenario.controller_params().apf_influence_m
    rest_m = min_slot_spacing_m(body_m, influence_m)
    tolerance_m = 1e-6
    problems = []
    slots = slot_positions_m(scenario)
    if closest_pair_m(slots) < rest_m - tolerance_m:
        problems.append(f"two slots are closer than {rest_m:.3f} m")
    starts = scenario.initial_poses()[:, :2]
    if closest_pair_m(starts) < 2 * body_m + START_MARGIN_M - tolerance_m:
        problems.append(f"two initial poses are closer than {2 * body_m + START_MARGIN_M:.3f} m")
    for k, obstacle in enumerate(scenario.obstacles):
        centre = np.asarray(obstacle.position_m)
        to_slots = np.hypot(*(slots - centre).T) - obstacle.radius_m
        if np.any(to_slots < body_m + influence_m - tolerance_m):
            problems.append(f"obstacle {k} is within the APF influence of a slot at t = 0")
        to_starts = np.hypot(*(starts - centre).T) - obstacle.radius_m
        if np.any(to_starts < body_m + START_MARGIN_M - tolerance_m):
            problems.append(f"obstacle {k} is too close to an initial pose")
    return problems


def _number(value: float, decimals: int) -> str:
    """A YAML float: fixed point, trailing zeros dropped, never '-0.0' or an exponent."""
    text = f"{round(value, decimals) + 0.0:.{decimals}f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text in ("-0.0", "0.0") else text


def _trajectory_lines(kind: str, size_m: float, speed_mps: float) -> list[str]:
    if kind == "circle":
        return [
            "  kind: circle",
            f"  radius_m: {_number(size_m, 4)}",
            f"  angular_rate_radps: {_number(speed_mps / size_m, 6)}",
            "  centre_m: [0.0, 0.0]",
            "  heading_deg: 90.0",
        ]
    if kind == "lemniscate":  # peak speed of the lemniscate of Gerono: √2·A·ω, at t = 0
        return [
            "  kind: lemniscate",
            f"  amplitude_m: {_number(size_m, 4)}",
            f"  angular_rate_radps: {_number(speed_mps / (math.sqrt(2.0) * size_m), 6)}",
            "  centre_m: [0.0, 0.0]",
            "  heading_deg: 90.0",
        ]
    a = _number(size_m, 4)
    return [
        "  kind: polyline",
        f"  waypoints_m: [[-{a}, -{a}], [{a}, -{a}], [{a}, {a}], [-{a}, {a}]]",
        f"  speed_mps: {_number(speed_mps, 4)}",
        "  closed: true",
        "  heading_deg: 90.0",
    ]


def _path_period_s(trajectory: TrajectorySpec) -> float:
    """One lap of the leader's path, s."""
    if isinstance(trajectory, PolylineSpec):
        path = trajectory.build()
        assert isinstance(path, PolylineTrajectory)
        return path.length_m / trajectory.speed_mps
    return 2.0 * math.pi / abs(trajectory.angular_rate_radps)


def _obstacle_centres(scenario: Scenario, count: int) -> list[tuple[float, float]]:
    """`count` points 5 cm outside the leader's path, the k-th first tried at k/(2·count) of a
    lap after the first third, then further along the path until it is clear of every slot at
    t = 0 (by the body radius + ρ₀) and of the obstacles before it (a robot passes between)."""
    body_m = scenario.robot_body.body_radius_m
    influence_m = scenario.controller_params().apf_influence_m
    slots = slot_positions_m(scenario)
    trajectory = scenario.trajectory.build()
    period_s = _path_period_s(scenario.trajectory)
    centres: list[tuple[float, float]] = []
    for k in range(count):
        for step in range(OBSTACLE_PATH_STEPS):
            t_s = period_s * (1.0 / 3.0 + 0.5 * k / count + step / OBSTACLE_PATH_STEPS)
            pose, rate = trajectory.evaluate(t_s)
            normal = np.array([rate[1], -rate[0]]) / max(math.hypot(rate[0], rate[1]), 1e-12)
            if float(normal @ pose[:2]) < 0.0:  # outside: away from the path's centre, the origin
                normal = -normal
            x_m, y_m = (round(float(v), 3) for v in pose[:2] + OBSTACLE_OFFSET_M * normal)
            to_slots_m = float(np.min(np.hypot(slots[:, 0] - x_m, slots[:, 1] - y_m)))
            if to_slots_m >= OBSTACLE_RADIUS_M + body_m + influence_m and all(
                math.hypot(x_m - o[0], y_m - o[1])
                >= 2.0 * (OBSTACLE_RADIUS_M + body_m) + influence_m
                for o in centres
            ):
                centres.append((x_m, y_m))
                break
        else:
            raise ScenarioGenerationError(
                f"{count} obstacles do not fit on this path, only {k} do (none may be near a "
                f"slot at the start, and a robot must pass between two); give a larger --size-m"
            )
    return centres


def _initial_poses(
    scenario: Scenario,
    spacing_m: float,
    rng: random.Random,
    obstacles: Sequence[tuple[float, float]],
) -> list[tuple[float, float, float]]:
    body_m = scenario.robot_body.body_radius_m
    apart_m = 2.0 * body_m + START_MARGIN_M
    clear_m = OBSTACLE_RADIUS_M + body_m + START_MARGIN_M
    poses: list[tuple[float, float, float]] = []
    for slot in slot_positions_m(scenario):
        for _ in range(PLACEMENT_ATTEMPTS):
            distance_m = spacing_m * rng.uniform(*START_OFFSET_SPACINGS)
            direction = rng.uniform(-math.pi, math.pi)
            heading_deg = 90.0 + rng.uniform(-START_HEADING_SPREAD_DEG, START_HEADING_SPREAD_DEG)
            x_m = round(float(slot[0]) + distance_m * math.cos(direction), 3)
            y_m = round(float(slot[1]) + distance_m * math.sin(direction), 3)
            if all(math.hypot(x_m - p[0], y_m - p[1]) >= apart_m for p in poses) and all(
                math.hypot(x_m - o[0], y_m - o[1]) >= clear_m for o in obstacles
            ):
                poses.append((x_m, y_m, round(heading_deg, 1)))
                break
        else:
            raise ScenarioGenerationError(
                f"found no free initial pose for robot {len(poses) + 1} in {PLACEMENT_ATTEMPTS} "
                "draws; try a larger --spacing-m or fewer --obstacles"
            )
    return poses


def _check_request(
    request: GenerateRequest, spacing_m: float, rest_m: float, max_speed_mps: float
) -> None:
    if not 1 <= request.robots <= MAX_ROBOTS:
        raise ScenarioGenerationError(
            f"--robots must be between 1 and {MAX_ROBOTS}, got {request.robots}"
        )
    if request.formation not in FORMATIONS:
        raise ScenarioGenerationError(
            f"unknown formation {request.formation!r}; known: {', '.join(FORMATIONS)}"
        )
    if request.trajectory not in TRAJECTORIES:
        raise ScenarioGenerationError(
            f"unknown trajectory {request.trajectory!r}; known: {', '.join(TRAJECTORIES)}"
        )
    if not (math.isfinite(spacing_m) and rest_m <= spacing_m <= 100.0):
        raise ScenarioGenerationError(
            f"--spacing-m must be between {rest_m:.2f} m (2 body radii + the APF influence "
            f"distance: closer robots push each other at their slots) and 100 m, got {spacing_m}"
        )
    if request.size_m is not None and not (
        math.isfinite(request.size_m) and 0.0 < request.size_m <= 1000.0
    ):
        raise ScenarioGenerationError(f"--size-m must be in (0, 1000] m, got {request.size_m}")
    speed = request.speed_mps
    if speed is not None and not (math.isfinite(speed) and 0.0 < speed <= max_speed_mps):
        raise ScenarioGenerationError(
            f"--speed-mps must be in (0, {max_speed_mps:.2f}] m/s (the wheels' top speed), "
            f"got {speed}"
        )
    if not 0 <= request.obstacles <= 64:
        raise ScenarioGenerationError(
            f"--obstacles must be between 0 and 64, got {request.obstacles}"
        )
    if request.name is not None and not re.fullmatch(SCENARIO_NAME_PATTERN, request.name):
        raise ScenarioGenerationError(
            f"--name must be 1-64 letters, digits, '_', '.' or '-', got {request.name!r}"
        )
    if request.seed < 0:
        raise ScenarioGenerationError(f"--seed must be >= 0, got {request.seed}")
    if not (math.isfinite(request.duration_s) and request.duration_s > 0.0):
        raise ScenarioGenerationError(f"--duration must be > 0 s, got {request.duration_s}")


def _check_written_values(
    request: GenerateRequest, size_m: float, speed_mps: float, control_period_s: float
) -> None:
    """Refuse, naming the flag, a value that the file's fixed decimals would turn into one the
    scenario cannot hold: a duration under one control period or over the tick limit, a size
    or a path rate that rounds to 0 (a speed of 1e-7 m/s wrote `angular_rate_radps: 0.0`, and
    the lap's period divided by it)."""
    duration_s = float(_number(request.duration_s, 3))
    if duration_s < control_period_s:
        raise ScenarioGenerationError(
            f"--duration must be at least one control period ({control_period_s:g} s; the file "
            f"keeps 3 decimals), got {request.duration_s:g}"
        )
    if duration_s / control_period_s > MAX_TICKS:
        raise ScenarioGenerationError(
            f"--duration must be at most {MAX_TICKS * control_period_s:g} s (ten million "
            f"control periods of {control_period_s:g} s), got {request.duration_s:g}"
        )
    if float(_number(size_m, 4)) <= 0.0:
        raise ScenarioGenerationError(
            f"--size-m must be at least 0.0001 m (the file keeps 4 decimals), got {size_m:g}"
        )
    if request.trajectory == "polyline":
        slowest_mps, written = 1e-4, float(_number(speed_mps, 4))
    else:  # the file holds the angular rate, 6 decimals: speed / size (circle), / √2·size
        per_rate = size_m if request.trajectory == "circle" else math.sqrt(2.0) * size_m
        slowest_mps, written = 1e-6 * per_rate, float(_number(speed_mps / per_rate, 6))
    if written <= 0.0:
        raise ScenarioGenerationError(
            f"--speed-mps {speed_mps:g} is too slow for a {request.trajectory} of "
            f"{_number(size_m, 4)} m: it rounds to a standstill in the file; give at least "
            f"{slowest_mps:.2g} m/s"
        )


def _exact_number(value: float) -> str:
    """`value` exactly, in the fewest digits that read back as the very same float (Python's
    repr), written in fixed point (`0.00001`, not `1e-05`)."""
    return format(Decimal(repr(float(value))), "f")


def command_line(
    request: GenerateRequest, spacing_m: float, size_m: float, speed_mps: float, name: str
) -> str:
    """The `swarm scenario generate` arguments that re-create the file (defaults spelt out).

    Every number is written exactly (`_exact_number`), not with the file's fixed decimals: a
    rounded flag gave another file (`--spacing-m 1.23456` came back as 1.2346, other slots),
    or one refused (`--speed-mps 0.00001` came back as 0.0)."""
    # A name that starts with '-' would read as a flag of its own: `--name=-x` is one argument.
    name_argument = f"--name={name}" if name.startswith("-") else f"--name {name}"
    return (
        f"swarm scenario generate --robots {request.robots} --formation {request.formation} "
        f"--spacing-m {_exact_number(spacing_m)} --trajectory {request.trajectory} "
        f"--size-m {_exact_number(size_m)} --speed-mps {_exact_number(speed_mps)} "
        f"--obstacles {request.obstacles} --seed {request.seed} "
        f"--duration {_exact_number(request.duration_s)} {name_argument}"
    )


def generate_scenario_text(request: GenerateRequest) -> str:
    """The scenario file for `request`, already parsed back and checked against the rules."""
    body = BodyParams()
    controller = ControllerParams()
    rest_m = min_slot_spacing_m(body.body_radius_m, controller.apf_influence_m)
    spacing_m = request.spacing_m
    if spacing_m is None:
        spacing_m = default_spacing_m(body.body_radius_m, controller.apf_influence_m)
    _check_request(
        request, spacing_m, rest_m, controller.max_wheel_speed_radps * body.wheel_radius_m
    )
    name = request.name or f"{request.formation}-{request.robots}"
    slots = formation_slots(request.formation, request.robots - 1, spacing_m)
    extent_m = max((distance for distance, _ in slots), default=0.0)
    defaults = TRAJECTORY_DEFAULTS[request.trajectory]
    size_m = request.size_m if request.size_m is not None else max(defaults.size_m, extent_m)
    speed_mps = request.speed_mps if request.speed_mps is not None else defaults.speed_mps
    _check_written_values(request, size_m, speed_mps, controller.control_period_s)

    header = [
        f"# {request.formation.capitalize()} of {request.robots} robots, written by",
        f"#   {command_line(request, spacing_m, size_m, speed_mps, name)}",
        f"# Slots are {_number(spacing_m, 4)} m apart or more (at rest no two bodies are "
        f"within the APF influence",
        f"# distance of {_number(controller.apf_influence_m, 3)} m); initial poses are "
        f"0.3-0.6 spacings from their slots, not overlapping.",
        "# An ordinary scenario file: edit it as you like (configs/scenarios/paper.yaml explains "
        "the fields).",
    ]
    description = (
        f"{request.formation.capitalize()} of {request.robots} robots "
        f"({_number(spacing_m, 4)} m spacing) behind a leader on a {request.trajectory} of "
        f"{_number(size_m, 4)} m at {_number(speed_mps, 4)} m/s, {request.obstacles} "
        f"obstacle{'s' if request.obstacles != 1 else ''} on its path."
    )
    top = [
        f"name: {name}",
        f"description: {json.dumps(description)}",
        f"seed: {request.seed}",
        f"duration_s: {_number(request.duration_s, 3)}",
        "",
        "trajectory:",
        *_trajectory_lines(request.trajectory, size_m, speed_mps),
        "",
    ]
    radio = ["", "radio:", f"  profile: {RADIO_PROFILE}", "  broadcast_rate_hz: 20.0"]

    def robot_lines(poses: Sequence[tuple[float, float, float]]) -> list[str]:
        lines = ["robots:"]
        for i, (x_m, y_m, heading_deg) in enumerate(poses):
            pose = (
                f"{{x_m: {_number(x_m, 3)}, y_m: {_number(y_m, 3)}, "
                f"heading_deg: {_number(heading_deg, 1)}}}"
            )
            if i == 0:
                lines += ["  - role: leader", f"    initial_pose: {pose}"]
            else:
                distance_m, angle_deg = slots[i - 1]
                lines += [
                    "  - role: follower",
                    f"    slot: {{distance_m: {_number(distance_m, 6)}, "
                    f"angle_deg: {_number(angle_deg, 6)}}}",
                    f"    initial_pose: {pose}",
                ]
        return lines

    def obstacle_lines(centres: Sequence[tuple[float, float]]) -> list[str]:
        if not centres:
            return ["obstacles: []"]
        lines = ["obstacles:"]
        for x_m, y_m in centres:
            lines += [
                f"  - position_m: [{_number(x_m, 3)}, {_number(y_m, 3)}]",
                f"    radius_m: {_number(OBSTACLE_RADIUS_M, 3)}",
            ]
        return lines

    def parse(text: str) -> Scenario:
        return parse_scenario(parse_yaml(text), f"<generated {name}>")

    # The slots at t = 0 need the trajectory only: place them with the robots at their slots
    # and no obstacles, then the obstacles, then the initial poses around them.  The
    # provisional starts, 10 m apart in rows of 16, stay well inside the positioning range
    # whatever the robot count.
    provisional = parse(
        "\n".join(
            [
                *top,
                *robot_lines(
                    [(10.0 * (i % 16), 10.0 * (i // 16), 90.0) for i in range(request.robots)]
                ),
                "",
                "obstacles: []",
                *radio,
                "",
            ]
        )
    )
    centres = _obstacle_centres(provisional, request.obstacles)
    poses = _initial_poses(provisional, spacing_m, random.Random(request.seed), centres)
    text = "\n".join([*header, *top, *robot_lines(poses), "", *obstacle_lines(centres), *radio, ""])
    problems = generation_problems(parse(text))
    if problems:
        raise ScenarioGenerationError(
            f"cannot place {request.robots} robots and {request.obstacles} obstacles: "
            f"{'; '.join(problems)}"
        )
    return text

"""One world step, batched over runs and robots: bodies, sensors and the radio medium.

The world evolves as a pure function in the manner of a Gymnasium environment:

    observation = sense_world(state, params, noise, fix_due, sonar_due)
    state, fates = step_world(state, WorldInputs(duty, dt_s, senders), params, noise)

`step_world` decides the fate of the frames the `senders` broadcast at the start of the step
(per link: delivered or lost, and the delay) from the positions they were sent from, then moves
the bodies for dt_s with the duty held (`world.physics.step_bodies`, the motor model and eq. 11)
and pushes overlapping bodies apart (`resolve_contacts`).  `sense_world` synthesises what the
robots' pins see: encoder counts, a positioning fix and the sonar ring (DESIGN.md §4-5), the
sonar hearing the obstacles and every other robot's body.  Every array has a leading batch shape
(..., N, ...): () for the world process, (B,) for the batch simulator's B runs.

Both the world process (`world.engine.WorldEngine`, through which the in-process firmware swarm
also runs) and the batch simulator (`services.sim.batch.run_batch`) call these functions; the
world engine broadcasts one sender at a time (`broadcast`, the radio half of the step) because
frames reach it whenever a robot sends one.

Randomness comes from one injected generator, split into one stream per noise source
(`WorldNoise`: positioning fix, sonar, radio links, wheel slip).  A source's draws therefore
do not depend on how often the other sources drew: two runs that schedule the radio differently
(the firmware broadcasts every robot in the same tick, the batch simulator staggers them) still
see the same fix, sonar and slip noise sample for sample.  Draws take the shape
`noise.batch_shape + (N, ...)`: () in the world process, (B,) for B runs with their own noise,
(1,) for B runs sharing the same noise (common random numbers, as a tuner comparing candidates
wants).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from swarm_config.body import BodyParams
from swarm_config.radio import LinkProfile
from swarm_config.scenario import Scenario
from swarm_config.sensors import PositioningParams, SonarParams
from world.physics import (
    BodyState,
    body_constants,
    encoder_counts,
    move_one_world,
    resolve_contacts,
    step_bodies,
)
from world.radio import LinkTable, draw_links
from world.sensors import pose_fix, sonar_gaps

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class WorldParams:
    """What the world is made of: bodies, sensors, the radio medium and the obstacles."""

    body: BodyParams
    sonar: SonarParams
    positioning: PositioningParams
    link: LinkProfile
    beam_angles_rad: FloatArray
    """(S,) transducer axes in the body frame."""
    obstacle_centres_m: FloatArray
    """(M, 2)"""
    obstacle_radii_m: FloatArray
    """(M,)"""
    link_table: LinkTable | None = None
    """Per-link profiles and cut links while a network fault is active (world/faults.py);
    None: every link has the profile `link`."""

    @classmethod
    def from_scenario(
        cls, scenario: Scenario, beam_angles_rad: Sequence[float] | None = None
    ) -> WorldParams:
        """The scenario's world; beam_angles_rad overrides the controller's sonar ring."""
        centres, radii = scenario.obstacle_arrays()
        beams = (
            scenario.controller_params().sonar_beam_angles_rad
            if beam_angles_rad is None
            else beam_angles_rad
        )
        return cls(
            body=scenario.robot_body,
            sonar=scenario.sensors.sonar,
            positioning=scenario.sensors.positioning,
            link=scenario.radio.link,
            beam_angles_rad=np.asarray(beams, dtype=np.float64),
            obstacle_centres_m=centres,
            obstacle_radii_m=radii,
        )


@dataclass(frozen=True)
class WorldNoise:
    """One generator per noise source, and the batch shape their draws take."""

    fix: np.random.Generator
    sonar: np.random.Generator
    radio: np.random.Generator
    slip: np.random.Generator
    batch_shape: tuple[int, ...] = ()

    @classmethod
    def spawn(cls, rng: np.random.Generator, batch_shape: tuple[int, ...] = ()) -> WorldNoise:
        """Independent streams for the four sources, spawned from `rng` (deterministically)."""
        fix, sonar, radio, slip = rng.spawn(4)
        return cls(fix=fix, sonar=sonar, radio=radio, slip=slip, batch_shape=batch_shape)


@dataclass(frozen=True)
class WorldState:
    """Ground truth of a batch of worlds."""

    bodies: BodyState
    """(..., N) bodies."""
    link_bad: BoolArray
    """(noise..., N, N) Gilbert-Elliott state of each link, sender x receiver."""
    contacts: BoolArray | None = None
    """(..., N, N + M) pairs that touched at the end of the last step (None before the first)."""

    @classmethod
    def at_rest(cls, pose: FloatArray, noise_batch_shape: tuple[int, ...] = ()) -> WorldState:
        """Bodies at rest at `pose` (..., N, 3), every link in its good state."""
        n = pose.shape[-2]
        return cls(
            bodies=BodyState.at_rest(pose),
            link_bad=np.zeros(noise_batch_shape + (n, n), dtype=bool),
        )

    @property
    def robot_count(self) -> int:
        return int(self.bodies.pose.shape[-2])


@dataclass(frozen=True)
class WorldInputs:
    """What the robots do during one step: duties held, and who broadcasts at its start."""

    duty: FloatArray
    """(..., N, 4) PWM duty per wheel."""
    dt_s: float
    senders: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(S,) indices of the robots that broadcast one frame each at the start of the step."""
    physics_substeps: int = 1
    """Split dt_s into this many body steps (the step is exact for a held duty; for comparison)."""


@dataclass(frozen=True)
class FrameFates:
    """What becomes of the frames of `senders` (S,) on each link to the N robots."""

    senders: IntArray
    delivered: BoolArray
    """(..., S, N); never to the sender itself."""
    delay_s: FloatArray
    """(..., S, N)"""


@dataclass(frozen=True)
class Observation:
    """What the robots' pins see: (..., N, ...); fix and sonar only when they refresh."""

    encoder_counts: IntArray
    """(..., N, 4) running counts after 4x quadrature decoding."""
    fix_pose: FloatArray | None
    """(..., N, 3) a positioning fix, or None when none is due."""
    sonar_gap_m: FloatArray | None
    """(..., N, S) gap from the rim to the nearest surface per transducer (inf: no echo)."""


def sonar_targets(
    positions_m: FloatArray, params: WorldParams
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """What the sonar can hear: the obstacles and every robot's body, as circles.

    positions_m (..., N, 2).  Returns centres (..., 1, M + N, 2) (the same for every sensing
    robot), radii (M + N,) and which targets each robot hears (N, M + N): not its own body.
    """
    n = positions_m.shape[-2]
    m = len(params.obstacle_radii_m)
    obstacles = np.broadcast_to(params.obstacle_centres_m, positions_m.shape[:-2] + (m, 2))
    centres = np.concatenate((obstacles, positions_m), axis=-2)[..., None, :, :]
    radii = np.concatenate((params.obstacle_radii_m, np.full(n, params.body.body_radius_m)))
    valid = np.concatenate((np.ones((n, m), dtype=bool), ~np.eye(n, dtype=bool)), axis=1)
    return centres, radii, valid


def sense_world(
    state: WorldState,
    params: WorldParams,
    noise: WorldNoise,
    fix_due: bool,
    sonar_due: bool,
) -> Observation:
    """Encoders always; a positioning fix and a sonar sweep when due (draws only then)."""
    bodies = state.bodies
    n = state.robot_count
    counts = encoder_counts(bodies.wheel_angle_rad, params.body.encoder_counts_per_rev)
    fix = None
    if fix_due:
        fix = pose_fix(
            bodies.pose, noise.fix.standard_normal(noise.batch_shape + (n, 3)), params.positioning
        )
    gaps = None
    if sonar_due:
        centres, radii, valid = sonar_targets(bodies.pose[..., :2], params)
        beams = params.beam_angles_rad
        gaps = sonar_gaps(
            bodies.pose,
            beams,
            centres,
            radii,
            valid,
            params.body.body_radius_m,
            noise.sonar.standard_normal(noise.batch_shape + (n, len(beams))),
            params.sonar,
        )
    return Observation(encoder_counts=counts, fix_pose=fix, sonar_gap_m=gaps)


def broadcast(
    state: WorldState, senders: IntArray, params: WorldParams, noise: WorldNoise
) -> tuple[WorldState, FrameFates]:
    """The fate of one frame from each of `senders` (S,) on its links to every robot.

    One draw per link (sender x receiver), self-links included so that the draws do not depend
    on who the sender is; a link's burst state moves only when a frame crosses it.  With a
    network fault active, each link has its own profile (`params.link_table`).
    """
    if senders.size == 0:
        empty = np.zeros(noise.batch_shape + (0, state.robot_count))
        return state, FrameFates(senders=senders, delivered=empty.astype(bool), delay_s=empty)
    positions = state.bodies.pose[..., :2]
    length_m = None
    if params.link.range_m is not None:
        d = positions[..., senders, None, :] - positions[..., None, :, :]
        length_m = np.hypot(d[..., 0], d[..., 1])
    links = params.link if params.link_table is None else params.link_table.rows(senders)
    draw = draw_links(links, state.link_bad[..., senders, :], length_m, noise.radio)
    link_bad = state.link_bad.copy()
    link_bad[..., senders, :] = draw.in_bad_state
    not_self = np.arange(state.robot_count) != senders[:, None]
    fates = FrameFates(senders=senders, delivered=draw.delivered & not_self, delay_s=draw.delay_s)
    return replace(state, link_bad=link_bad), fates


def step_world(
    state: WorldState, inputs: WorldInputs, params: WorldParams, noise: WorldNoise
) -> tuple[WorldState, FrameFates]:
    """One step: the senders' frames meet the radio, then the bodies move and collide."""
    state, fates = broadcast(state, inputs.senders, params, noise)
    n = state.robot_count
    bodies = state.bodies
    duty = np.asarray(inputs.duty, dtype=np.float64)
    sub_dt_s = inputs.dt_s / inputs.physics_substeps
    for _ in range(inputs.physics_substeps):
        slip_noise = noise.slip.standard_normal(noise.batch_shape + (n, 4))
        bodies = step_bodies(bodies, duty, sub_dt_s, slip_noise, params.body)
    positions, report = resolve_contacts(
        bodies.pose[..., :2],
        params.body.body_radius_m,
        params.obstacle_centres_m,
        params.obstacle_radii_m,
    )
    pose = bodies.pose.copy()
    pose[..., :2] = positions
    bodies = replace(bodies, pose=pose)
    contacts = np.concatenate((report.robot_robot, report.robot_obstacle), axis=-1)
    return replace(state, bodies=bodies, contacts=contacts), fates


def move_world(
    state: WorldState, duty: FloatArray, dt_s: float, params: WorldParams, noise: WorldNoise
) -> WorldState:
    """`step_world` of one world (batch shape ()) with no senders and one physics sub-step:
    the bodies move for dt_s with the duty held and collide, in one compiled call
    (`world.physics.move_one_world`) instead of the batched functions' layout and wrapping.
    The world engine steps its bodies this way at every act it takes; the numbers and the
    slip draws are `step_world`'s, bit for bit (tests/world/test_step.py)."""
    bodies = state.bodies
    body = params.body
    pose, speed, angle, slip, contacts = move_one_world(
        bodies.pose,
        bodies.wheel_speed_radps,
        bodies.wheel_angle_rad,
        bodies.slip,
        np.asarray(duty, dtype=np.float64),
        noise.slip.standard_normal((state.robot_count, 4)),
        float(dt_s),
        body_constants(body),
        float(body.body_radius_m),
        np.asarray(params.obstacle_centres_m, dtype=np.float64).reshape(-1, 2),
        np.asarray(params.obstacle_radii_m, dtype=np.float64).reshape(-1),
    )
    return WorldState(
        bodies=BodyState(pose=pose, wheel_speed_radps=speed, wheel_angle_rad=angle, slip=slip),
        link_bad=state.link_bad,
        contacts=contacts,
    )

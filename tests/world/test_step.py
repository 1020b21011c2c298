"""The batched world step: pure, seeded, batched, and shared by the world engine."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from swarm_config.radio import BurstLoss, LinkProfile
from swarm_config.scenario import load_scenario
from swarm_config.sensors import SonarParams
from world.engine import NS_PER_S, WorldEngine
from world.step import (
    Observation,
    WorldInputs,
    WorldNoise,
    WorldParams,
    WorldState,
    broadcast,
    move_world,
    sense_world,
    step_world,
)

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
TICKS = 40
DT_S = 0.01
BURSTY = LinkProfile(
    latency_ms=20.0, jitter_ms=10.0, burst=BurstLoss(good_to_bad=0.3, bad_to_good=0.3)
)


def _paper_params(link: LinkProfile | None = None) -> tuple[WorldParams, np.ndarray]:
    scenario = load_scenario(PAPER)
    params = WorldParams.from_scenario(scenario)
    if link is not None:
        params = replace(params, link=link)
    return params, scenario.initial_poses()


def _roll_out(
    seed: int,
    params: WorldParams,
    pose: np.ndarray,
    duty: np.ndarray,
    batch_shape: tuple[int, ...] = (),
    noise_batch_shape: tuple[int, ...] = (),
    broadcast_every: int = 2,
) -> list[tuple[Observation, WorldState]]:
    """TICKS steps with fixed duties; fixes and sonar every 5th tick, robot k % N broadcasts."""
    noise = WorldNoise.spawn(np.random.default_rng(seed), noise_batch_shape)
    n = pose.shape[-2]
    state = WorldState.at_rest(
        np.broadcast_to(pose, batch_shape + (n, 3)).copy(), noise.batch_shape
    )
    out = []
    for k in range(TICKS):
        seen = sense_world(state, params, noise, fix_due=k % 5 == 0, sonar_due=k % 5 == 0)
        senders = np.array([k % n] if k % broadcast_every == 0 else [], dtype=np.int64)
        state, _ = step_world(state, WorldInputs(duty, DT_S, senders), params, noise)
        out.append((seen, state))
    return out


def _flat(trace: list[tuple[Observation, WorldState]]) -> list[np.ndarray]:
    arrays: list[np.ndarray] = []
    for seen, state in trace:
        arrays += [seen.encoder_counts, state.bodies.pose, state.bodies.slip, state.link_bad]
        arrays += [a for a in (seen.fix_pose, seen.sonar_gap_m) if a is not None]
    return arrays


def test_same_seed_gives_the_same_trace_and_another_seed_does_not() -> None:
    params, pose = _paper_params(BURSTY)
    duty = np.full((3, 4), 0.4)
    first, again, other = (_flat(_roll_out(s, params, pose, duty)) for s in (5, 5, 6))
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(first, other, strict=True))


def test_the_step_leaves_its_input_state_unchanged() -> None:
    params, pose = _paper_params(BURSTY)
    noise = WorldNoise.spawn(np.random.default_rng(1))
    state = WorldState.at_rest(pose)
    before = [
        state.bodies.pose.copy(),
        state.bodies.wheel_speed_radps.copy(),
        state.link_bad.copy(),
    ]
    after, fates = step_world(
        state, WorldInputs(np.full((3, 4), 0.5), DT_S, np.array([0, 2])), params, noise
    )
    after_arrays = (after.bodies.pose, after.bodies.wheel_speed_radps, after.link_bad)
    inputs_now = (state.bodies.pose, state.bodies.wheel_speed_radps, state.link_bad)
    for old, new, now in zip(before, inputs_now, after_arrays, strict=True):
        np.testing.assert_array_equal(old, new)
        assert not np.array_equal(old, now)
    assert fates.delivered.shape == (2, 3)


def test_sources_draw_from_their_own_streams_whatever_the_radio_does() -> None:
    """Broadcasting every tick or never leaves the fix, sonar and slip noise sample for sample."""
    params, pose = _paper_params(LinkProfile(latency_ms=5.0, loss=0.5))
    duty = np.full((3, 4), 0.4)
    chatty = _roll_out(9, params, pose, duty, broadcast_every=1)
    silent = _roll_out(9, params, pose, duty, broadcast_every=TICKS + 1)
    for (seen_a, state_a), (seen_b, state_b) in zip(chatty, silent, strict=True):
        np.testing.assert_array_equal(state_a.bodies.pose, state_b.bodies.pose)
        for a, b in ((seen_a.fix_pose, seen_b.fix_pose), (seen_a.sonar_gap_m, seen_b.sonar_gap_m)):
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_array_equal(a, b)


def test_a_batch_of_worlds_under_shared_noise_equals_each_world_alone() -> None:
    params, pose = _paper_params(BURSTY)
    duties = np.stack([np.full((3, 4), 0.2), np.full((3, 4), -0.5), np.full((3, 4), 0.2)])
    batch = _roll_out(4, params, pose, duties, batch_shape=(3,), noise_batch_shape=(1,))
    alone = _roll_out(4, params, pose, duties[1])
    for (seen_b, state_b), (seen_1, state_1) in zip(batch, alone, strict=True):
        np.testing.assert_array_equal(state_b.bodies.pose[1], state_1.bodies.pose)
        np.testing.assert_array_equal(state_b.bodies.pose[0], state_b.bodies.pose[2])
        np.testing.assert_array_equal(state_b.link_bad[0], state_1.link_bad)
        np.testing.assert_array_equal(seen_b.encoder_counts[1], seen_1.encoder_counts)
        if seen_1.sonar_gap_m is not None:
            assert seen_b.sonar_gap_m is not None
            np.testing.assert_array_equal(seen_b.sonar_gap_m[1], seen_1.sonar_gap_m)
    assert not np.array_equal(batch[-1][1].bodies.pose[0], batch[-1][1].bodies.pose[1])


def test_independent_noise_differs_across_the_batch() -> None:
    params, pose = _paper_params()
    batch = _roll_out(
        4, params, pose, np.full((3, 4), 0.3), batch_shape=(2,), noise_batch_shape=(2,)
    )
    seen = batch[0][0]  # the first tick: same pose, different fix noise
    assert seen.fix_pose is not None
    assert not np.array_equal(seen.fix_pose[0], seen.fix_pose[1])
    assert not np.array_equal(batch[-1][1].bodies.pose[0], batch[-1][1].bodies.pose[1])


def test_frames_never_reach_their_sender_and_only_used_links_change_burst_state() -> None:
    always_bad = LinkProfile(burst=BurstLoss(good_to_bad=1.0, bad_to_good=1.0, loss_in_bad=0.0))
    params, pose = _paper_params(always_bad)
    state = WorldState.at_rest(pose)
    noise = WorldNoise.spawn(np.random.default_rng(2))
    state, fates = broadcast(state, np.array([1]), params, noise)
    np.testing.assert_array_equal(fates.delivered, [[True, False, True]])
    expected = np.zeros((3, 3), dtype=bool)
    expected[1] = True  # every link from robot 1 went bad; the others never carried a frame
    np.testing.assert_array_equal(state.link_bad, expected)


def test_a_robot_hears_the_others_bodies_and_the_obstacles_but_not_itself() -> None:
    params, _ = _paper_params()
    params = replace(
        params,
        sonar=SonarParams(noise_std_m=0.0),
        beam_angles_rad=np.array([0.0, np.pi]),
        obstacle_centres_m=np.array([[-2.0, 0.0]]),
        obstacle_radii_m=np.array([0.2]),
    )
    pose = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, np.pi]])  # facing each other, 1.5 m apart
    seen = sense_world(
        WorldState.at_rest(pose),
        params,
        WorldNoise.spawn(np.random.default_rng(0)),
        fix_due=False,
        sonar_due=True,
    )
    r = params.body.body_radius_m
    assert seen.fix_pose is None and seen.sonar_gap_m is not None
    # Robot 0: the peer ahead (1.5 - 2r), the obstacle behind (2.0 - 0.2 - r).
    np.testing.assert_allclose(seen.sonar_gap_m[0], [1.5 - 2 * r, 2.0 - 0.2 - r])
    # Robot 1: the peer ahead; behind it, nothing within range.
    np.testing.assert_allclose(seen.sonar_gap_m[1], [1.5 - 2 * r, np.inf])


def test_overlapping_bodies_are_pushed_apart_and_the_contact_is_reported() -> None:
    params, _ = _paper_params()
    r = params.body.body_radius_m
    params = replace(params, obstacle_centres_m=np.zeros((0, 2)), obstacle_radii_m=np.zeros(0))
    state = WorldState.at_rest(np.array([[0.0, 0.0, 0.0], [2 * r - 0.1, 0.0, 0.0]]))
    assert state.contacts is None
    after, _ = step_world(
        state,
        WorldInputs(np.zeros((2, 4)), DT_S),
        params,
        WorldNoise.spawn(np.random.default_rng(0)),
    )
    assert after.contacts is not None
    np.testing.assert_array_equal(after.contacts, [[False, True], [True, False]])
    gap = np.hypot(*(after.bodies.pose[1, :2] - after.bodies.pose[0, :2]))
    assert gap >= 2 * r - 1e-9


def test_the_world_engine_takes_the_same_step() -> None:
    """The engine's sense, transmit and advance are the step's, from the same seed."""
    scenario = load_scenario(PAPER)
    link = LinkProfile(latency_ms=5.0, jitter_ms=3.0, loss=0.3)  # every frame lands in its tick
    radio = scenario.radio.model_copy(update={"profile": link})
    scenario = scenario.model_copy(update={"radio": radio})
    engine = WorldEngine(scenario, seed=11)
    params = WorldParams.from_scenario(scenario)
    noise = WorldNoise.spawn(np.random.default_rng(11))
    state = WorldState.at_rest(scenario.initial_poses())
    duty = np.array([[0.3, -0.2, 0.1, 0.5], [0.0, 0.4, 0.4, 0.0], [-0.6, 0.2, 0.2, 0.1]])
    period_ns = 10_000_000
    for k in range(20):
        messages = engine.sense()
        seen = sense_world(state, params, noise, fix_due=k % 5 == 0, sonar_due=k % 5 == 0)
        assert [m.encoder_counts for m in messages] == [tuple(c) for c in seen.encoder_counts]
        if seen.fix_pose is not None:
            assert [(m.fix.x_m, m.fix.y_m) for m in messages if m.fix] == [
                tuple(p) for p in seen.fix_pose[:, :2]
            ]
        sender = k % 3
        engine.transmit(sender, bytes([k]))
        state, fates = step_world(
            state, WorldInputs(duty, period_ns / NS_PER_S, np.array([sender])), params, noise
        )
        engine.advance(duty, period_ns)
        np.testing.assert_array_equal(engine.bodies.pose, state.bodies.pose)
        expected = [(r, sender, bytes([k])) for r in range(3) if fates.delivered[0, r]]
        assert sorted(engine.due_frames()) == expected
    assert engine.radio.dropped > 0 and engine.radio.delivered > 0


def test_links_longer_than_the_radio_range_carry_nothing_in_every_run_of_a_batch() -> None:
    params, pose = _paper_params(LinkProfile(range_m=1.6))  # robot1-robot2 1.58 m, others more
    state = WorldState.at_rest(np.broadcast_to(pose, (4, 3, 3)).copy(), (1,))
    noise = WorldNoise.spawn(np.random.default_rng(0), (1,))  # runs share the noise
    _, fates = broadcast(state, np.array([0, 1]), params, noise)
    expected = [[False, True, False], [True, False, False]]
    np.testing.assert_array_equal(fates.delivered, np.broadcast_to(expected, (4, 2, 3)))


def test_one_world_moved_in_one_call_is_step_world_bit_for_bit() -> None:
    """`move_world` (the world engine's step) against `step_world` with no senders: the same
    poses, wheel states, slips, slip draws and contacts, with robots driven into each other and
    into the obstacle so that contacts and pushes happen."""
    params, pose = _paper_params()
    n = pose.shape[0]
    # Everyone drives at the first obstacle, and robot2 onto robot1's spot.
    obstacle = params.obstacle_centres_m[0]
    start = np.array(pose, dtype=np.float64)
    start[:, :2] = obstacle + np.array([[-0.3, 0.0], [0.3, 0.05], [0.0, -0.31]])
    start[1, :2] = start[0, :2] + [0.05, 0.0]
    rng = np.random.default_rng(11)
    states = [WorldState.at_rest(start.copy()), WorldState.at_rest(start.copy())]
    noises = [WorldNoise.spawn(np.random.default_rng(3)) for _ in states]
    touched = 0
    for _ in range(200):
        duty = rng.uniform(-1.0, 1.0, (n, 4))
        dt_s = float(rng.choice((0.0005, 0.001, 0.01)))
        states[0], _ = step_world(states[0], WorldInputs(duty, dt_s), params, noises[0])
        states[1] = move_world(states[1], duty, dt_s, params, noises[1])
        batched, one = states
        for field_name in ("pose", "wheel_speed_radps", "wheel_angle_rad", "slip"):
            np.testing.assert_array_equal(
                getattr(one.bodies, field_name), getattr(batched.bodies, field_name)
            )
        assert one.contacts is not None and batched.contacts is not None
        np.testing.assert_array_equal(one.contacts, batched.contacts)
        np.testing.assert_array_equal(one.link_bad, batched.link_bad)
        touched += int(one.contacts.any())
    assert touched > 0
    assert noises[0].slip.standard_normal() == noises[1].slip.standard_normal()

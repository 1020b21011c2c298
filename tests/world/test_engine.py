from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from swarm_config.radio import LinkProfile
from swarm_config.scenario import load_scenario
from world.engine import NS_PER_S, SPEED_OF_SOUND_MPS, WorldEngine

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def _engine(profile: str | LinkProfile) -> WorldEngine:
    scenario = load_scenario(PAPER)
    radio = scenario.radio.model_copy(update={"profile": profile})
    return WorldEngine(scenario.model_copy(update={"radio": radio}))


@pytest.mark.parametrize(
    "profile",
    [
        LinkProfile(latency_ms=50.0, jitter_ms=20.0, loss=0.2),
        LinkProfile(latency_ms=5.0, jitter_ms=2.0, loss=0.05),
    ],
)
def test_radio_medium_delivery_ratio_and_delay_match_the_profile(profile: LinkProfile) -> None:
    engine = _engine(profile)
    step_ns = 1_000_000
    for k in range(3000):  # 3,000 broadcasts to 2 receivers = 6,000 frames
        engine.transmit(k % 3, k.to_bytes(4, "little"))
        engine.advance(np.zeros((3, 4)), step_ns)
        engine.due_frames()
    for _ in range(200):
        engine.advance(np.zeros((3, 4)), step_ns)
        engine.due_frames()
    radio = engine.radio
    frames = 2 * radio.sent
    assert frames >= 5000
    assert radio.delivered + radio.dropped == frames
    assert abs(radio.delivered / frames - (1.0 - profile.loss)) <= 0.015
    mean_delay_ms = float(np.mean(radio.latencies_ns)) / 1e6
    # Delivery is checked on a 1 ms grid, so a frame waits up to one step beyond its delay.
    assert abs(mean_delay_ms - (profile.latency_ms + 0.5)) <= 1.0


def test_frames_are_never_delivered_to_their_sender_and_arrive_after_the_delay() -> None:
    engine = _engine(LinkProfile(latency_ms=30.0))
    engine.transmit(1, b"hello")
    engine.advance(np.zeros((3, 4)), 29 * 1_000_000)
    assert engine.due_frames() == []
    engine.advance(np.zeros((3, 4)), 1_000_000)
    assert sorted(engine.due_frames()) == [(0, 1, b"hello"), (2, 1, b"hello")]


def test_a_frame_sent_at_the_clock_is_due_its_delay_later_without_a_physics_step() -> None:
    """The real-time world sends and delivers frames at its clock, which runs ahead of the
    physics between steps: the delay counts from the time given, and `due_frames` takes any
    time, not only the engine's."""
    engine = _engine(LinkProfile(latency_ms=30.0))
    engine.transmit(1, b"hello", sent_ns=7_000_000)
    assert engine.next_frame_due_ns() == 37_000_000
    assert engine.due_frames(36_999_999) == []
    assert sorted(engine.due_frames(37_000_000)) == [(0, 1, b"hello"), (2, 1, b"hello")]
    assert engine.t_ns == 0
    assert engine.radio.latency_percentile_ms(50) == 30.0


def test_compiling_the_kernels_changes_nothing_the_engine_does() -> None:
    """`compile_kernels` runs on scratch copies and a scratch generator: an engine that ran it
    senses, steps, sends frames and takes metrics exactly as one that did not."""
    engines = [_engine("lab"), _engine("lab")]
    engines[0].compile_kernels()
    duty = np.linspace(-0.6, 0.9, 12).reshape(3, 4)
    for k in range(300):
        seen = []
        for engine in engines:
            if k % 7 == 0:
                engine.transmit(k % 3, bytes([k % 256]) * 16)
            pins = engine.sense_pins()
            engine.advance(duty, 10_000_000)
            seen.append(
                (
                    pins.encoder_counts.tolist(),
                    None if pins.fix_pose is None else pins.fix_pose.tolist(),
                    np.nan_to_num(pins.echo_times_s, nan=-1.0).tolist(),
                    engine.bodies.pose.tolist(),
                    engine.bodies.slip.tolist(),
                    engine.due_frames(),
                )
            )
        assert seen[0] == seen[1]
    first, second = (engine.metrics.summaries() for engine in engines)
    assert first == second
    assert engines[0].radio.sent == engines[1].radio.sent > 0


def test_sense_messages_carry_encoders_sonar_and_fixes_on_schedule() -> None:
    engine = _engine("ideal")
    first = engine.sense()
    assert len(first) == 3
    assert all(m.fix is not None for m in first)
    assert all(len(m.sonar_echo_times_s) == 12 for m in first)
    engine.advance(np.full((3, 4), 0.3), 10_000_000)
    second = engine.sense()
    assert all(m.fix is None for m in second)  # fixes come at 20 Hz
    assert any(c != 0 for c in second[0].encoder_counts)
    echo = [t for m in first for t in m.sonar_echo_times_s if t is not None]
    assert echo and all(0.0 < t < 2 * 3.0 / SPEED_OF_SOUND_MPS for t in echo)
    engine.fixes_cut[1] = True
    engine.advance(np.zeros((3, 4)), 40_000_000)
    third = engine.sense()
    assert third[1].fix is not None and not third[1].fix.valid
    assert engine.t_ns == 50_000_000 and engine.t_s == 50_000_000 / NS_PER_S


def test_every_contact_that_begins_is_a_collision_with_its_time_and_what_was_touched() -> None:
    engine = _engine("ideal")
    pose = engine.bodies.pose.copy()
    pose[1, :2] = pose[0, :2] + [0.5, 0.0]  # robot2's body 0.1 m into robot1's
    pose[2, :2] = [-0.78 + 0.4, 1.34]  # robot3's body 0.05 m into the obstacle
    engine.state = replace(engine.state, bodies=replace(engine.bodies, pose=pose))
    period_ns = engine.metrics_period_ns
    engine.advance(np.zeros((3, 4)), period_ns)
    assert engine.collisions == [(0.0, "robot1", "robot2"), (0.0, "robot3", "obstacle 1")]
    engine.collisions.clear()
    for _ in range(5):  # the bodies are pushed apart and stay touching: no new onset
        engine.advance(np.zeros((3, 4)), period_ns)
    assert engine.collisions == []
    assert engine.summary()["collisions"] == 2

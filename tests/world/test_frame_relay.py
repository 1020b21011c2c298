"""How the world passes radio frames on in real time (world/runtime.py `_relay_frames`,
`_pass_frames_on`), without a network: the receivers' publishers record what they are given
(each put a bundle of frames, robot_firmware/net/radio_bundle.py).

Frames leave the queue only under the engine's lock: by the relay thread while the main loop
sleeps, or by the main loop's own drain while it is awake, and always in arrival order.
tests/integration/test_radio_relay.py checks the same over a real router.
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

from robot_firmware.net.radio_bundle import split_bundle
from swarm_config.scenario import load_scenario
from tests.support.waiting import wait_for
from world.runtime import WorldConfig, WorldProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


class RecordingPublisher:
    """A receiver's `radio/rx` publisher: each frame of each bundle put, as (receiver,
    sequence), in order; and how many frames each put carried."""

    def __init__(self, receiver: str, out: list[tuple[str, int]], bundles: list[int]) -> None:
        self.receiver = receiver
        self.out = out
        self.bundles = bundles

    def put(self, payload: bytes) -> None:
        frames = split_bundle(payload)
        self.out.extend((self.receiver, int(struct.unpack_from("<Q", f, 8)[0])) for f in frames)
        self.bundles.append(len(frames))


def frame(claimed_sender: int, sequence: int) -> bytes:
    return struct.pack("<IHHQ", 0, claimed_sender, 0, sequence) + bytes(16)


def real_time_world(
    profile: bytes = b'{"profile": "ideal"}', bundles: list[int] | None = None
) -> tuple[WorldProcess, list[tuple[str, int]]]:
    """A real-time world of the paper scenario on the link profile `profile` (a body of
    `admin/world/net`); the frames each put on `radio/rx` carried go to `bundles`."""
    world = WorldProcess(WorldConfig(scenario=PAPER), load_scenario(PAPER))
    world._net_request(profile)
    delivered: list[tuple[str, int]] = []
    sizes = [] if bundles is None else bundles
    world._rx_publishers = [  # type: ignore[misc]
        RecordingPublisher(name, delivered, sizes) for name in world.names
    ]
    return world, delivered


def queue_frame(world: WorldProcess, sender: str, payload: bytes) -> None:
    """What the subscriber's callback does with a frame in real time."""
    world._frames.put((sender, payload))
    world._frames_queued.set()


def test_an_awake_main_loop_passes_queued_frames_on_in_arrival_order() -> None:
    """One pass: each receiver's frames in one bundle, in arrival order; the receivers in the
    order of their first frame."""
    bundles: list[int] = []
    world, delivered = real_time_world(bundles=bundles)
    queue_frame(world, "robot1", frame(0, 1))
    queue_frame(world, "robot3", frame(2, 2))
    queue_frame(world, "robot2", frame(0, 3))  # robot2 claiming robot1's id: dropped
    queue_frame(world, "robot9", frame(8, 4))  # no such transmitter: dropped
    queue_frame(world, "robot1", frame(0, 5))
    world._drain()
    assert delivered == [
        ("robot2", 1), ("robot2", 2), ("robot2", 5),
        ("robot3", 1), ("robot3", 5),
        ("robot1", 2),
    ]  # fmt: skip
    assert bundles == [3, 2, 1]
    assert (world.spoofed_frames, world.unknown_senders) == (1, 1)
    assert world.engine.radio.sent == 3
    assert world._frames.empty()


def test_the_relay_thread_passes_frames_on_only_under_the_engine_lock() -> None:
    world, delivered = real_time_world()
    relay = threading.Thread(target=world._relay_frames, daemon=True)
    with world._engine_lock:  # the main loop is awake
        relay.start()
        queue_frame(world, "robot1", frame(0, 7))
        time.sleep(0.2)
        assert delivered == []
        assert not world._frames.empty()
    # The main loop sleeps: the relay takes the frame.
    wait_for(lambda: len(delivered) == 2 or None, 10.0, 0.01, "the relayed frame")
    assert delivered == [("robot2", 7), ("robot3", 7)]
    with world._engine_lock:
        world._relay_stopping = True
    world._frames_queued.set()
    relay.join(timeout=10.0)
    assert not relay.is_alive()


def test_a_delayed_frame_leaves_with_the_first_pass_after_its_due_time_and_wakes_nothing() -> None:
    """On a link with a delay the relay draws the frame when it comes and leaves it in the
    engine's queue; nothing wakes for its due time.  It leaves with the medium's first pass at
    or after that time (a drain of the main loop here), at the latest with the next sense
    message, with the delay it was drawn."""
    world, delivered = real_time_world(b'{"latency_ms": 40.0, "jitter_ms": 0.0, "loss": 0.0}')
    world.guard.start(0, 0, 0, time.monotonic_ns())  # the clock runs, as `_run_realtime` starts it
    world.guard.published(1_000)  # and its own sense ticks do not hold it
    world._time_started = True
    relay = threading.Thread(target=world._relay_frames, daemon=True)
    relay.start()
    world._wake.clear()
    queue_frame(world, "robot1", frame(0, 9))
    wait_for(lambda: world.engine.radio.sent == 1 or None, 10.0, 0.005, "the frame drawn")
    time.sleep(0.1)  # past its due time, with no pass of the medium
    assert delivered == []
    assert not world._wake.is_set()
    with world._engine_lock:  # the main loop wakes (for anything) and drains
        world._drain()
        assert delivered == [("robot2", 9), ("robot3", 9)]
        # The next one leaves with the sense message at the first tick past its due time.
        world._frames.put(("robot3", frame(2, 10)))
        world._pass_frames_on()
        due_ns = world.engine.next_frame_due_ns()
        assert due_ns is not None and delivered[2:] == []
        world.engine.advance(world.duty, due_ns - world.engine.t_ns)
        assert world._deliver_radio() == [1, 1, 0]  # what `_publish_sense` announces
        assert delivered[2:] == [("robot1", 10), ("robot2", 10)]
        world._relay_stopping = True
    assert world.engine.radio.latency_percentile_ms(50) == 40.0
    world._frames_queued.set()
    relay.join(timeout=10.0)
    assert not relay.is_alive()

"""The world's radio relay in real time, over a real router with its access control: the test
plays the robots' radios (robot1 transmits, robot2 and robot3 listen) against a real world
process with no robot processes, so every frame on the air is one the test sent.

In real time the world relays frames on a thread of its own (world/runtime.py
`_relay_frames`): a frame on an ideal link leaves as soon as it comes; a frame with a delay is
queued in the engine and the main loop delivers it when it falls due.
"""

from __future__ import annotations

import json
import signal
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import WorldStatusReply
from robot_firmware.net.radio_bundle import split_bundle
from robot_firmware.net.session import open_client
from services.router.access import router_config_document
from swarm_config.credentials import (
    ROUTER_USERS_FILE,
    generate_credential_set,
    read_credentials,
    write_credential_set,
    write_private_file,
)
from tests.integration.conftest import PAPER, ROOT, free_port
from tests.support.waiting import wait_for

pytestmark = pytest.mark.slow

KEYS = SwarmKeys("lab")
ROBOTS = ("robot1", "robot2", "robot3")
FRAME_BYTES = 64


def frame(claimed_sender: int, sequence: int) -> bytes:
    """An opaque frame whose header claims `claimed_sender` (frames.py `claimed_sender`)."""
    head = struct.pack("<IHH", 0x5357524D, claimed_sender, 0) + struct.pack("<Q", sequence)
    return head + bytes(FRAME_BYTES - len(head))


def port_open(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def sequence_of(payload: bytes) -> int:
    return int(struct.unpack_from("<Q", payload, 8)[0])


@dataclass
class Inbox:
    """The frames one robot's `radio/rx` key carried (in bundles), in arrival order."""

    frames: list[bytes] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.frames.extend(split_bundle(sample.payload.to_bytes()))

    def sequences(self) -> list[int]:
        with self.lock:
            return [sequence_of(f) for f in self.frames]


@dataclass
class Medium:
    world: subprocess.Popen[str]
    sessions: dict[str, zenoh.Session]
    inboxes: dict[str, Inbox]

    def await_frames(self, count: int, receivers: tuple[str, ...] = ("robot2", "robot3")) -> None:
        wait_for(
            lambda: all(len(self.inboxes[r].frames) >= count for r in receivers) or None,
            30.0,
            0.05,
            f"{count} frames at {', '.join(receivers)}",
        )

    def send(self, robot: str, claimed_sender: int, sequences: range) -> None:
        publisher = self.sessions[robot].declare_publisher(KEYS.radio_tx(robot))
        for sequence in sequences:
            publisher.put(frame(claimed_sender, sequence))
        publisher.undeclare()

    def status(self) -> WorldStatusReply | None:
        for reply in self.sessions["operator"].get(KEYS.admin("world", "status"), timeout=3.0):
            if reply.ok is not None:
                return WorldStatusReply.model_validate_json(reply.ok.payload.to_bytes())
        return None

    def set_profile(self, body: dict[str, float]) -> dict:
        payload = json.dumps(body).encode()
        for reply in self.sessions["operator"].get(
            KEYS.admin("world", "net"), payload=payload, timeout=3.0
        ):
            if reply.ok is not None:
                return dict(json.loads(reply.ok.payload.to_bytes()))
        raise AssertionError("the world did not answer admin/world/net")


@pytest.fixture
def medium(tmp_path: Path) -> Iterator[Medium]:
    """A router with the run's access control, a real-time world (ideal radio, no robot
    processes), and a logged-in session per robot and for the operator."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    credentials = generate_credential_set("lab", ROBOTS)
    files = write_credential_set(tmp_path / "credentials", credentials)
    router_config = tmp_path / "credentials" / "router.json5"
    document = router_config_document(
        credentials, tmp_path / "credentials" / ROUTER_USERS_FILE, [endpoint]
    )
    write_private_file(router_config, json.dumps(document).encode())
    cli = [sys.executable, "-m", "services.cli.main"]
    with ExitStack() as stack:
        router = subprocess.Popen(
            [*cli, "router", "--listen", endpoint, "--config", str(router_config)], cwd=ROOT
        )
        stack.callback(router.wait, timeout=30)
        stack.callback(router.terminate)
        port = int(endpoint.rsplit(":", 1)[1])
        wait_for(lambda: router.poll() is not None or port_open(port), 30.0, 0.1, "the router")
        assert router.poll() is None, "the router did not start"
        world = subprocess.Popen(
            [
                *cli,
                "world",
                "--scenario",
                str(PAPER),
                "--radio",
                "ideal",
                "--connect",
                endpoint,
                "--credentials",
                str(files["world"]),
            ],
            cwd=ROOT,
            text=True,
        )
        stack.callback(lambda: world.poll() is None and world.kill())
        sessions = {
            name: stack.enter_context(
                open_client([endpoint], credentials=read_credentials(files[name]))
            )
            for name in (*ROBOTS, "operator")
        }
        inboxes = {name: Inbox() for name in ROBOTS}
        for name, inbox in inboxes.items():
            sessions[name].declare_subscriber(KEYS.radio_rx(name), inbox)
        found = Medium(world, sessions, inboxes)
        wait_for(found.status, 60.0, 0.2, "the world's status")
        yield found


def test_frames_are_relayed_in_order_and_spoofed_ones_dropped(medium: Medium) -> None:
    inboxes = medium.inboxes
    # Ideal links: relayed as they come, by the relay thread.
    medium.send("robot1", 0, range(0, 40))
    medium.await_frames(40)
    # robot2's transmitter claiming robot1's id: the medium knows the antenna.
    medium.send("robot2", 0, range(1000, 1010))
    # Links with a delay: queued in the engine, delivered by the main loop when due.
    reply = medium.set_profile({"latency_ms": 40.0, "jitter_ms": 0.0, "loss": 0.0})
    assert reply["profile"]["latency_ms"] == 40.0
    medium.send("robot1", 0, range(40, 60))
    medium.await_frames(60)

    def counted() -> WorldStatusReply | None:
        status = medium.status()
        return status if status is not None and status.radio.delivered >= 120 else None

    status = wait_for(counted, 10.0, 0.1, "the world's radio counters")
    for receiver in ("robot2", "robot3"):
        assert inboxes[receiver].sequences() == list(range(60)), receiver
        assert all(len(f) == FRAME_BYTES for f in inboxes[receiver].frames)
    assert inboxes["robot1"].frames == []  # nobody's frame comes back to its sender
    assert status.radio.broadcasts == 60  # the 10 spoofed frames never went on the air
    assert status.radio.frames == status.radio.delivered == 120
    assert status.radio.dropped == 0
    assert status.radio.latency_p99_ms == pytest.approx(40.0)
    assert medium.world.poll() is None
    medium.world.send_signal(signal.SIGTERM)
    assert medium.world.wait(timeout=30) == 0  # the relay thread ends with the world

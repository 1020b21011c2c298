"""Attacks on a running swarm (`swarm up --lockstep` on loopback) by clients that are not the
operator: none may connect without credentials, and with another identity's credentials none
may write, steer, serve, ask, jam or kill anything beyond what that identity is allowed.

Every attempt is counted, and so is every attempt that got through, as the swarm shows it:
an operator tap subscribed to every key of the swarm counts the attacker's marker payloads
that reached anyone, the world's radio profile, robot1's scratch register and the processes
are read back through the operator, and robot1's inbox (`radio/rx/robot1`) is watched for
frames the attacker signed. Goal: 0 accepted. The counts are printed (pytest -s).
Broken radio bundles put on robot1's inbox with the world's own identity are dropped and
counted by robot1, which runs on.
"""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections import Counter

import pytest
import zenoh

from robot_firmware.net.frames import (
    FRAME_BYTES,
    RadioFrame,
    Role,
    derive_frame_key,
    encode,
    initial_sequence,
    swarm_hash_from_name,
)
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.radio_bundle import split_bundle
from robot_firmware.net.session import client_config
from services.router.access import (
    ACT_AND_FRAME_BYTES_MAX,
    MESSAGE_BYTES_MAX,
    TELEMETRY_BYTES_MAX,
)
from swarm_config.credentials import ProcessCredentials, read_credentials
from tests.integration.conftest import LiveSwarm
from tests.support.waiting import wait_for
from world.input_budget import BURST, PER_PERIOD

pytestmark = pytest.mark.slow

SWARM = "lab"
KEYS = SwarmKeys(SWARM)
MARKERS = {"robot2": b"ATTACK-robot2-7f3a", "dashboard": b"ATTACK-dashboard-7f3a"}
MARKER_X_M = 777.25
"""Frames the attacker signs carry this x: robot1's inbox is searched for it."""
SCRATCH = 0xFF200010
CONNECT_TIMEOUT_MS = 3000


def _credentials(live: LiveSwarm, identity: str) -> ProcessCredentials:
    return read_credentials(live.out / "credentials" / f"{identity}.json")


def _open(live: LiveSwarm, credentials: ProcessCredentials | None, **login: str) -> zenoh.Session:
    """A plain client of the swarm's router, failing fast instead of waiting for it."""
    config = client_config([live.endpoint], None, credentials)
    if login:
        config.insert_json5("transport/auth/usrpwd", json.dumps(login))
    config.insert_json5("connect/timeout_ms", json.dumps(CONNECT_TIMEOUT_MS))
    return zenoh.open(config)


class Tap:
    """The operator's view of every key of the swarm: whose marker reached which key, and
    the attacker's frames that reached robot1's inbox."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.markers: Counter[tuple[str, str]] = Counter()
        self.inbox_marked_frames = 0

    def on_sample(self, sample: zenoh.Sample) -> None:  # zenoh callback: count and return
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        with self._lock:
            for who, marker in MARKERS.items():
                if marker in data:
                    self.markers[(who, key)] += 1
            if key == KEYS.radio_rx("robot1"):
                self.inbox_marked_frames += sum(
                    len(frame) == FRAME_BYTES and struct.pack("<d", MARKER_X_M) in frame
                    for frame in split_bundle(data)
                )

    def count(self, who: str) -> int:
        with self._lock:
            return sum(n for (sender, _key), n in self.markers.items() if sender == who)


def _signed_frame(secret: bytes, run_id: bytes, sender_id: int, now_ns: int) -> bytes:
    frame = RadioFrame(
        role=Role.LEADER,
        sender_id=sender_id,
        swarm_hash=swarm_hash_from_name(SWARM),
        run_id=run_id,
        sequence=initial_sequence(now_ns) + 2**20,
        timestamp_ns=now_ns,
        x_m=MARKER_X_M,
        y_m=0.0,
        theta_rad=0.0,
        xdot_mps=0.0,
        ydot_mps=0.0,
        thetadot_radps=0.0,
        localised=True,
    )
    return encode(frame, derive_frame_key(secret, SWARM))


def _put_rounds(
    session: zenoh.Session, key: str, payloads: list[bytes], rounds: int, pause_s: float
) -> None:
    """Put every payload on `key`, in order, `rounds` times, pausing `pause_s` after each round."""
    for _ in range(rounds):
        for payload in payloads:
            session.put(key, payload)
        time.sleep(pause_s)


def _replies(session: zenoh.Session, key: str, payload: bytes | None = None) -> list[bytes]:
    return [
        bytes(reply.ok.payload.to_bytes())
        for reply in session.get(key, payload=payload, timeout=2.0)
        if reply.ok is not None
    ]


@pytest.mark.parametrize("live_swarm", [("--lockstep", "--max-speed", "2")], indirect=True)
def test_no_identity_but_the_operator_can_read_steer_jam_or_kill(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    status = live.all_running()
    pids_before = {name: p["pid"] for name, p in status["processes"].items()}
    live.wait_for(lambda: live.admin("net", "get").get("ok"))
    profile_before = live.admin("net", "get")["profile"]
    scratch_before = live.cli("regs", "robot1", hex(SCRATCH)).stdout.split()[-1]

    attempts: Counter[str] = Counter()
    accepted: Counter[str] = Counter()

    # 1. Without credentials, or with a wrong password: no session at all.
    for login in (
        {},
        {"user": "robot1", "password": "0" * 64},
        {"user": "intruder", "password": "x"},
    ):
        attempts["connect without valid credentials"] += 1
        try:
            session = _open(live, None, **login)
        except zenoh.ZError:
            continue
        accepted["connect without valid credentials"] += 1
        session.close()

    operator = _open(live, _credentials(live, "operator"))
    tap = Tap()
    operator.declare_subscriber(KEYS.everything, tap.on_sample)
    robot2_creds = _credentials(live, "robot2")
    robot2 = _open(live, robot2_creds)
    dashboard = _open(live, _credentials(live, "dashboard"))
    truth_seen = threading.Event()
    dashboard.declare_subscriber(KEYS.truth, lambda _sample: truth_seen.set())
    time.sleep(1.0)

    # 2. robot2 writes robot1's and the world's keys (a put that passes reaches the tap).
    others = [
        KEYS.act("robot1"),
        KEYS.radio_tx("robot1"),
        KEYS.telemetry("robot1"),
        KEYS.sense("robot1"),
        KEYS.radio_rx("robot1"),
        KEYS.clock,
        KEYS.truth,
        KEYS.admin("robot1", "regs"),
    ]
    for key in others:
        for _ in range(5):
            attempts["robot2 puts on keys not its own"] += 1
            robot2.put(key, MARKERS["robot2"])
    # 3. robot2 signs frames with the swarm key it holds, claiming to be robot1 and robot3,
    #    on every way into robot1's inbox.
    secret, run_id = robot2_creds.swarm_key_bytes(), robot2_creds.run_id_bytes
    world_t_ns = int(live.wait_for(lambda: _world_t_ns(operator)))
    for sender_id in (0, 2):
        for key in (KEYS.radio_tx("robot2"), KEYS.radio_tx("robot1"), KEYS.radio_rx("robot1")):
            for step in range(5):
                attempts["robot2 frames signed as robot1 or robot3"] += 1
                robot2.put(key, _signed_frame(secret, run_id, sender_id, world_t_ns + step))
    # 4. robot2 serves admin verbs of robot1, the world and the launcher.
    fakes = [
        robot2.declare_queryable(
            KEYS.admin(target, "*"), lambda q: q.reply(q.key_expr, MARKERS["robot2"])
        )
        for target in ("robot1", "world", "launcher")
    ]
    token = robot2.liveliness().declare_token(KEYS.alive("robot", "robot9"))
    time.sleep(1.0)
    for target, verb in (("robot1", "status"), ("world", "status"), ("launcher", "status")):
        attempts["robot2 serves admin verbs"] += 1
        accepted["robot2 serves admin verbs"] += sum(
            MARKERS["robot2"] in reply for reply in _replies(operator, KEYS.admin(target, verb))
        )
    attempts["robot2 declares a token not its own"] += 1
    accepted["robot2 declares a token not its own"] += sum(
        "robot9" in str(reply.ok.key_expr)
        for reply in operator.liveliness().get(KEYS.alive_all("robot"), timeout=2.0)
        if reply.ok is not None
    )
    for fake in fakes:  # robot2's own session would answer its own queries locally
        fake.undeclare()
    token.undeclare()
    # 5. robot2 and the dashboard ask the state-changing verbs (and the reads).
    requests = [
        (KEYS.admin("world", "net"), b'{"loss": 1.0}'),
        (
            KEYS.admin("robot1", "regs"),
            json.dumps({"op": "write", "address": SCRATCH, "value": 0xBAD}).encode(),
        ),
        (
            KEYS.admin("robot1", "params"),
            b"error_centres: [-1.0, 0.0, 1.0]\nrate_centres: [-1.0, 1.0]\n",
        ),
        (KEYS.admin("launcher", "kill"), b'{"robot": "robot1"}'),
        (KEYS.admin("launcher", "restart"), b'{"robot": "robot3"}'),
        (KEYS.admin("robot1", "status"), None),
        (KEYS.admin("launcher", "status"), None),
    ]
    for who, session in (("robot2", robot2), ("dashboard", dashboard)):
        for key, body in requests:
            attempts[f"{who} asks admin verbs"] += 1
            accepted[f"{who} asks admin verbs"] += len(_replies(session, key, body))
    # 6. The dashboard may read but not write.
    for key in (KEYS.truth, KEYS.clock, KEYS.act("robot1"), KEYS.radio_rx("robot1")):
        for _ in range(5):
            attempts["dashboard puts"] += 1
            dashboard.put(key, MARKERS["dashboard"])
    time.sleep(2.0)

    accepted["robot2 puts on keys not its own"] = tap.count("robot2")
    accepted["dashboard puts"] = tap.count("dashboard")
    accepted["robot2 frames signed as robot1 or robot3"] = tap.inbox_marked_frames
    markers = dict(tap.markers)
    for session in (robot2, dashboard):
        session.close()
    operator.close()

    # What the swarm shows afterwards, through the operator.
    after = live.admin("status")
    pids_after = {name: p["pid"] for name, p in after["processes"].items()}
    profile_after = live.admin("net", "get")["profile"]
    scratch_after = live.cli("regs", "robot1", hex(SCRATCH)).stdout.split()[-1]
    print("\nattacks on a live swarm (attempts, accepted):")
    for what in attempts:
        print(f"  {what:<45} {attempts[what]:>4} {accepted[what]:>4}")
    print(
        f"  dashboard read truth: {truth_seen.is_set()}; processes unchanged: "
        f"{pids_after == pids_before}; radio profile unchanged: {profile_after == profile_before}; "
        f"robot1 scratch register {scratch_before} -> {scratch_after}; markers seen: {markers}"
    )
    assert sum(attempts.values()) > 100
    assert sum(accepted.values()) == 0, accepted
    assert markers == {}
    assert truth_seen.is_set()
    assert pids_after == pids_before and all(p["running"] for p in after["processes"].values())
    assert profile_after == profile_before
    assert scratch_after == scratch_before


@pytest.mark.parametrize("live_swarm", [("--lockstep", "--max-speed", "2")], indirect=True)
def test_a_robot_lying_in_its_telemetry_cannot_crash_the_world_or_speak_for_another(
    live_swarm: LiveSwarm,
) -> None:
    """In lockstep, robot2 puts, on its own telemetry key (which the router lets it), stamps
    no run reaches, samples naming robot3 as the leader of a term far ahead, and samples naming
    itself the leader of that term stamped 1000 s ahead of the world's clock (which, taken,
    would wait in the world until then and hold back robot2's later samples).  The world must
    stay up (same process), count each sample as malformed, and keep robot1 as the leader."""
    live = live_swarm
    status = live.all_running()
    world_pid = status["processes"]["world"]["pid"]
    live.wait_for(lambda: (live.out / "summary.json").exists(), 60)
    robot2 = _open(live, _credentials(live, "robot2"))
    operator = _open(live, _credentials(live, "operator"))
    world_t_s = live.wait_for(lambda: _world_t_ns(operator)) / 1e9
    ahead = {"robot": "robot2", "t_s": world_t_s + 1000.0, "role": "leader", "term": 999}
    lies = [
        b'{"robot": "robot2", "t_s": NaN}',
        b'{"robot": "robot2", "t_s": Infinity}',
        b'{"robot": "robot2", "t_s": 1e300}',
        json.dumps({"robot": "robot3", "t_s": world_t_s, "role": "leader", "term": 999}).encode(),
        json.dumps(ahead).encode(),
    ]
    repeats = 5
    _put_rounds(robot2, KEYS.telemetry("robot2"), lies, repeats, 0.1)
    robot2.close()
    operator.close()

    def counted() -> dict | None:  # the summary is written every 5 s
        summary = json.loads((live.out / "summary.json").read_text())
        return summary if summary["malformed_telemetry"] >= repeats * len(lies) else None

    summary = live.wait_for(counted, 30, describe="every lie counted as malformed telemetry")
    after = live.admin("status")["processes"]["world"]
    print(
        f"\nrobot2's lies: {repeats * len(lies)} sent, {summary['malformed_telemetry']} counted "
        f"malformed; world pid {world_pid} -> {after['pid']}; leader {summary['leader']}"
    )
    assert after["pid"] == world_pid and after["running"]
    assert summary["malformed_telemetry"] == repeats * len(lies)
    assert summary["leader"] == "robot1"
    assert "Traceback" not in (live.out / "logs" / "world.log").read_text()
    events = (live.out / "events.jsonl").read_text().splitlines()
    assert not [e for e in events if json.loads(e).get("kind") == "leader_change"], events


def _frame_counters(operator: zenoh.Session, robot: str) -> dict[str, int] | None:
    replies = _replies(operator, KEYS.admin(robot, "status"))
    if not replies:
        return None
    frames = json.loads(replies[0]).get("frames")
    return frames if isinstance(frames, dict) and frames.get("accepted") else None


def test_malformed_radio_bundles_are_dropped_and_counted_by_the_robot(
    live_swarm: LiveSwarm,
) -> None:
    """Messages on robot1's `radio/rx` key that are no well-formed bundle (empty, a length
    running past the end, a whole record then a cut one), put with the world's own identity
    (the only one the router lets put there): robot1 stays up, counts each broken piece as a
    frame too short, takes the whole record's frame to its decoder too, and goes on hearing its
    peers."""
    live = live_swarm
    status = live.all_running()
    robot1_pid = status["processes"]["robot1"]["pid"]
    operator = _open(live, _credentials(live, "operator"))
    before = live.wait_for(lambda: _frame_counters(operator, "robot1"), 30)
    world = _open(live, _credentials(live, "world"))
    whole_record = struct.pack("<I", 3) + b"abc"
    broken = [
        b"",
        struct.pack("<I", FRAME_BYTES) + bytes(10),
        whole_record + struct.pack("<I", 5) + b"ab",
    ]
    repeats = 5
    _put_rounds(world, KEYS.radio_rx("robot1"), broken, repeats, 0.05)
    world.close()
    expected_short = repeats * (len(broken) + 1)  # the whole 3-byte record is too short too

    def counted() -> dict[str, int] | None:
        now = _frame_counters(operator, "robot1")
        short = None if now is None else now["too_short"] - before["too_short"]
        return now if short is not None and short >= expected_short else None

    after = live.wait_for(counted, 30, describe="robot1 counting the broken bundles")

    def hears_on() -> dict[str, int] | None:
        now = _frame_counters(operator, "robot1")
        return now if now is not None and now["accepted"] > after["accepted"] else None

    later = live.wait_for(hears_on, 30, describe="robot1 still hearing its peers")
    operator.close()
    print(
        f"\nrobot1's frame counters: too_short {before['too_short']} -> {after['too_short']}, "
        f"accepted {before['accepted']} -> {after['accepted']} -> {later['accepted']}"
    )
    assert after["too_short"] - before["too_short"] == expected_short
    running = live.admin("status")["processes"]["robot1"]
    assert running["pid"] == robot1_pid and running["running"]
    assert "Traceback" not in (live.out / "logs" / "robot1.log").read_text()


def test_a_robot_cannot_put_messages_over_the_size_limits(live_swarm: LiveSwarm) -> None:
    """robot2 puts, on its own act, radio and telemetry keys, a message at each key's limit,
    one a byte over it and one over the router's link limit, each starting with a marker.
    The operator's tap, subscribed to every key, must see exactly the three at their limits;
    the world must count exactly those (as malformed: they are padding, not messages)."""
    live = live_swarm
    live.all_running()
    live.wait_for(lambda: (live.out / "summary.json").exists(), 60)
    before = json.loads((live.out / "summary.json").read_text())
    operator = _open(live, _credentials(live, "operator"))
    marker = MARKERS["robot2"]
    seen: list[tuple[str, int]] = []
    seen_lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:  # zenoh callback: record and return
        data = sample.payload.to_bytes()
        if data.startswith(marker):
            with seen_lock:
                seen.append((str(sample.key_expr), len(data)))

    operator.declare_subscriber(KEYS.everything, on_sample)
    robot2 = _open(live, _credentials(live, "robot2"))
    time.sleep(1.0)
    limits = {
        KEYS.act("robot2"): ACT_AND_FRAME_BYTES_MAX,
        KEYS.radio_tx("robot2"): ACT_AND_FRAME_BYTES_MAX,
        KEYS.telemetry("robot2"): TELEMETRY_BYTES_MAX,
    }
    for key, limit in limits.items():
        for size in (limit, limit + 1, MESSAGE_BYTES_MAX + 1, 8 * MESSAGE_BYTES_MAX):
            robot2.put(key, marker + bytes(size - len(marker)))
            time.sleep(0.2)
    robot2.close()

    def counted() -> dict | None:  # the summary is written every 5 s
        summary = json.loads((live.out / "summary.json").read_text())
        return summary if summary["malformed_acts"] > before["malformed_acts"] else None

    live.wait_for(counted, 30, describe="the act at its limit counted as malformed")
    time.sleep(6.0)  # one more summary: anything else that got through is counted by now
    after = json.loads((live.out / "summary.json").read_text())
    operator.close()
    with seen_lock:
        seen_sorted = sorted(seen)
    print(
        f"\nrobot2's puts at, over and far over the limits: the tap saw {seen_sorted}; the world "
        f"counted {after['malformed_acts'] - before['malformed_acts']} malformed acts and "
        f"{after['malformed_telemetry'] - before['malformed_telemetry']} malformed telemetry"
    )
    assert seen_sorted == sorted(limits.items())
    assert after["malformed_acts"] - before["malformed_acts"] == 1
    assert after["malformed_telemetry"] - before["malformed_telemetry"] == 1
    assert "Traceback" not in (live.out / "logs" / "world.log").read_text()


def test_a_robot_flooding_its_radio_gets_no_more_on_the_air_than_its_budget(
    live_swarm: LiveSwarm,
) -> None:
    """robot2 puts signed frames in its own name (valid: the medium would relay each to every
    other robot) as fast as it can for two seconds.  robot1's inbox may carry no more of them
    than robot2's budget allows over the whole time it was watched (world/input_budget.py);
    the rest are counted over budget, and no other robot and no other kind of robot2's
    messages loses any."""
    live = live_swarm
    status = live.all_running()
    world_pid = status["processes"]["world"]["pid"]
    live.wait_for(lambda: (live.out / "summary.json").exists(), 60)
    operator = _open(live, _credentials(live, "operator"))
    tap = Tap()
    operator.declare_subscriber(KEYS.radio_rx("robot1"), tap.on_sample)
    credentials = _credentials(live, "robot2")
    robot2 = _open(live, credentials)
    secret, run_id = credentials.swarm_key_bytes(), credentials.run_id_bytes
    world_t_ns = int(live.wait_for(lambda: _world_t_ns(operator)))
    publisher = robot2.declare_publisher(KEYS.radio_tx("robot2"))
    watched_from_s = time.monotonic()
    sent = 0
    while time.monotonic() - watched_from_s < 2.0:
        frame = _signed_frame(secret, run_id, 1, world_t_ns + sent)
        for _ in range(100):
            publisher.put(frame)
        sent += 100
    robot2.close()
    time.sleep(1.0)
    # Whatever reached the inbox by now passed the budget by now: at most what robot2 had
    # saved (BURST) and what it earned since the flood began.  The budget refills per control
    # period (10 ms) on the faster of the world's two clocks; in real time simulated time
    # runs no faster than the wall clock, so the wall clock bounds it (a second of margin).
    relayed = tap.inbox_marked_frames
    watched_s = time.monotonic() - watched_from_s + 1.0
    allowed = BURST + PER_PERIOD * round(watched_s / 0.010)

    def counted() -> dict | None:  # the summary is written every 5 s
        summary = json.loads((live.out / "summary.json").read_text())
        over = summary.get("over_budget", {}).get("frame", {}).get("robot2", 0)
        return summary if over > 0 else None

    summary = live.wait_for(counted, 30, describe="robot2's frames counted over budget")
    operator.close()
    over = summary["over_budget"]
    print(
        f"\nrobot2 put {sent} signed frames in 2 s: {relayed} reached robot1's inbox in "
        f"{watched_s:.1f} s (budget {allowed}); over budget {over}"
    )
    assert sent >= 10 * allowed, "the flood was too slow to test the budget"
    assert 0 < relayed <= allowed
    assert over["frame"]["robot2"] > 0
    assert all(
        n == 0
        for kind, counts in over.items()
        for who, n in counts.items()
        if (kind, who) != ("frame", "robot2")
    ), over
    after = live.admin("status")["processes"]["world"]
    assert after["pid"] == world_pid and after["running"]


def _world_t_ns(operator: zenoh.Session) -> float | None:
    replies = _replies(operator, KEYS.admin("world", "status"))
    if not replies:
        return None
    status = json.loads(replies[0])
    t_s = status.get("t_s")
    return None if t_s is None else float(t_s) * 1e9 + 1


def test_operator_tap_would_see_a_marker(live_swarm: LiveSwarm) -> None:
    """The observer itself works: a put an identity may make reaches the operator's tap."""
    live = live_swarm
    live.wait_for(lambda: live.admin("status").get("ok"))
    listener = _open(live, _credentials(live, "operator"))
    tap = Tap()
    listener.declare_subscriber(KEYS.everything, tap.on_sample)
    time.sleep(1.0)
    credentials = _credentials(live, "robot2")
    robot2 = _open(live, credentials)
    for _ in range(5):
        robot2.put(KEYS.telemetry("robot2"), MARKERS["robot2"])  # its own key: allowed
    world_t_ns = int(live.wait_for(lambda: _world_t_ns(listener)))
    secret, run_id = credentials.swarm_key_bytes(), credentials.run_id_bytes
    for step in range(5):  # frames robot2 signs as itself (index 1) reach robot1's inbox
        robot2.put(KEYS.radio_tx("robot2"), _signed_frame(secret, run_id, 1, world_t_ns + step))
    time.sleep(1.0)
    robot2.close()
    listener.close()
    print(
        f"\ncontrol: robot2's own telemetry key carried {tap.count('robot2')} marker samples, "
        f"robot1's inbox {tap.inbox_marked_frames} of 5 frames robot2 signed as itself"
    )
    assert tap.markers[("robot2", KEYS.telemetry("robot2"))] == 5
    assert tap.inbox_marked_frames >= 1


def test_no_secret_in_logs_summary_status_or_telemetry(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    live.wait_for(lambda: live.admin("status").get("ok"))
    live.wait_for(lambda: (live.out / "summary.json").exists(), 60)
    secrets = set()
    for path in (live.out / "credentials").glob("*.json"):
        data = json.loads(path.read_text())
        secrets.add(data["password"])
        if "swarm_key" in data:
            secrets.add(data["swarm_key"])
    operator = _open(live, _credentials(live, "operator"))
    telemetry: list[bytes] = []
    operator.declare_subscriber(
        KEYS.telemetry_all, lambda sample: telemetry.append(sample.payload.to_bytes())
    )
    replies = [
        reply
        for target in ("launcher", "world", "robot1", "robot2", "robot3")
        for reply in _replies(operator, KEYS.admin(target, "status"))
    ]
    live.wait_for(lambda: len(telemetry) >= 10, 30)
    operator.close()
    texts = {
        "summary.json": (live.out / "summary.json").read_bytes(),
        "status replies": b"\n".join(replies),
        "telemetry": b"\n".join(telemetry[:200]),
        "swarm status": live.cli("status").stdout.encode(),
        "swarm status robot2": live.cli("status", "robot2").stdout.encode(),
    }
    texts |= {f"logs/{p.name}": p.read_bytes() for p in (live.out / "logs").glob("*.log")}
    found = {name: sum(s.encode() in text for s in secrets) for name, text in texts.items()}
    print(f"\nsecrets ({len(secrets)}) found in: {found}")
    assert len(secrets) == 8 + 1  # a password per identity, and the robots' shared key
    assert len(replies) == 5
    assert all(count == 0 for count in found.values()), found
    robot2_status = json.loads(texts["swarm status robot2"])  # `swarm status PROCESS`
    assert robot2_status["robot"] == "robot2" and robot2_status["timing"]["ticks"] > 0


def test_idle_connections_held_to_the_router_keep_no_login_out(live_swarm: LiveSwarm) -> None:
    # Before, a hundred idle TCP connections to the router's port filled Zenoh's room for
    # logins (100 at once, each kept 10 s): `swarm status` could not log in within its 5 s,
    # nor could a restarted robot, for as long as someone held them.
    live = live_swarm
    held: list[socket.socket] = []
    try:
        for _ in range(300):
            held.append(socket.create_connection(("127.0.0.1", live.port), timeout=5))
        status = live.cli("status")
        assert status.returncode == 0, status.stderr
        assert live.cli("restart", "robot3").returncode == 0
        wait_for(lambda: live.cli("status", "robot3").returncode == 0, timeout_s=60)
    finally:
        for connection in held:
            connection.close()

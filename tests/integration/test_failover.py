"""Leader failover as real processes: `swarm kill robot1` in lockstep, later `swarm restart robot1`.

The test records every radio frame the robots put on `radio/tx/*` (before the radio medium, so
none is lost), decoded with the run's frame key and run id, and every `truth` message.  From
them, DESIGN.md §7 "killing the leader" and the election rule (robot_firmware/leadership.py):

* robot2, the live follower with the lowest index, sends its first leader frame within 1 s of
  simulation time after robot1's last frame (in lockstep the robots go by frames alone, not by
  the liveliness token: robot1 is lost once silent for the leader time-out, 0.5 s);
* no collision in the whole run (robot1's body stays parked on the circle robot2 now flies);
* robot2 tracks the trajectory and robot3 holds its slot relative to robot2: both back under
  5 cm within 15 s of robot2's first leader frame;
* the restarted robot1 sends only follower frames, adopts robot2's term and drives into the slot
  robot2 vacated;
* summary.json records the failover as a `leader_change` event (robot1 -> robot2, its term);
* exactly one acting leader at every instant: in every broadcast period at most one robot
  claims the lead, terms never go back, each term has one leader, and the only period with no
  leader is the failover gap.
"""

from __future__ import annotations

import itertools
import json
import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import zenoh

from robot_firmware.control.formation import follower_slot_in_world
from robot_firmware.leadership import slot_of
from robot_firmware.net.frames import RadioFrame, Role, derive_frame_key, parse_frame
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from swarm_config.credentials import read_credentials
from swarm_config.scenario import load_scenario
from tests.integration.conftest import PAPER, LiveSwarm

pytestmark = pytest.mark.slow

SWARM = "lab"
KEYS = SwarmKeys(SWARM)
_SCENARIO = load_scenario(PAPER)
ROBOTS = _SCENARIO.robot_names
LEADER = _SCENARIO.leader_index
SLOTS = tuple(
    (r.slot.distance_m, math.radians(r.slot.angle_deg)) if r.slot else (0.0, 0.0)
    for r in _SCENARIO.robots
)
BROADCAST_PERIOD_S = 1.0 / _SCENARIO.radio.broadcast_rate_hz
KILL_AFTER_S = 12.0
RESTART_AFTER_KILL_S = 18.0
RUN_AFTER_RESTART_S = 20.0
TAKEOVER_WITHIN_S = 1.0
FORMATION_BOUND_M = 0.05
FORMATION_WITHIN_S = 15.0


@dataclass(frozen=True)
class Sent:
    t_s: float
    sender: int
    leads: bool
    term: int


class Recorder:
    """Every radio frame put on `radio/tx/*` (decoded) and every truth message."""

    def __init__(self, key: bytes, run_id: bytes) -> None:
        self._key = key
        self._run_id = run_id
        self._lock = threading.Lock()
        self.frames: list[Sent] = []
        self.truth: list[dict[str, Any]] = []
        self.undecodable = 0

    def on_frame(self, sample: zenoh.Sample) -> None:  # zenoh callback: store and return
        frame = parse_frame(sample.payload.to_bytes(), self._key, run_id=self._run_id)
        with self._lock:
            if isinstance(frame, RadioFrame):
                sent = Sent(
                    frame.timestamp_ns / 1e9, frame.sender_id, frame.role == Role.LEADER, frame.term
                )
                self.frames.append(sent)
            else:
                self.undecodable += 1

    def on_truth(self, sample: zenoh.Sample) -> None:
        message = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.truth.append(message)

    def snapshot(self) -> tuple[list[Sent], list[dict[str, Any]]]:
        with self._lock:
            return sorted(self.frames, key=lambda s: (s.t_s, s.sender)), list(self.truth)


@contextmanager
def _recording(live: LiveSwarm) -> Iterator[Recorder]:
    robot_credentials = read_credentials(live.out / "credentials" / "robot2.json")
    key = derive_frame_key(robot_credentials.swarm_key_bytes(), SWARM)
    recorder = Recorder(key, robot_credentials.run_id_bytes)
    with open_client([live.endpoint]) as session:
        frames = session.declare_subscriber(KEYS.radio_tx_all, recorder.on_frame)
        truth = session.declare_subscriber(KEYS.truth, recorder.on_truth)
        try:
            yield recorder
        finally:
            frames.undeclare()
            truth.undeclare()


def _world_t_s(live: LiveSwarm) -> float:
    with open_client([live.endpoint]) as session:
        for reply in session.get(KEYS.admin("world", "status"), timeout=3.0):
            if reply.ok is not None:
                status = json.loads(reply.ok.payload.to_bytes())
                return float(status.get("t_s", -1.0))
    return -1.0


def _error_m(truth: dict[str, Any], robot: int, leader: int) -> float:
    """Robot's position error at one truth instant with `leader` leading: against the
    trajectory for the leader, against its slot (eq. 17, re-referenced) for a follower."""
    poses = truth["robots"]
    pose = poses[ROBOTS[robot]]["pose"]
    if robot == leader:
        reference = truth["reference"]
        return math.hypot(pose[0] - reference[0], pose[1] - reference[1])
    distance_m, angle_rad = slot_of(robot, leader, LEADER, SLOTS)
    slot = follower_slot_in_world(np.array(poses[ROBOTS[leader]]["pose"]), distance_m, angle_rad)
    return math.hypot(pose[0] - float(slot[0]), pose[1] - float(slot[1]))


def _first_time_under(
    truth: list[dict[str, Any]], robot: int, leader: int, start_s: float, hold_s: float = 1.0
) -> float | None:
    """The first time after start_s from which the robot's error stays under the bound for
    hold_s."""
    since = None
    for message in truth:
        t_s = message["t_s"]
        if t_s < start_s:
            continue
        if _error_m(message, robot, leader) < FORMATION_BOUND_M:
            since = t_s if since is None else since
            if t_s - since >= hold_s:
                return since
        else:
            since = None
    return None


@pytest.mark.parametrize("live_swarm", [("--lockstep", "--max-speed", "2")], indirect=True)
def test_killed_leader_is_replaced_and_returns_as_a_follower(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    with _recording(live) as recorder:
        live.wait_for(lambda: _world_t_s(live) >= KILL_AFTER_S, timeout_s=180)
        assert live.admin("kill", ROBOTS[LEADER])["killed"]
        kill_seen_s = _world_t_s(live)
        live.wait_for(lambda: _world_t_s(live) >= kill_seen_s + RESTART_AFTER_KILL_S, 180)
        restarted = live.admin("restart", ROBOTS[LEADER])
        assert restarted["ok"], restarted
        restart_seen_s = _world_t_s(live)
        live.wait_for(lambda: _world_t_s(live) >= restart_seen_s + RUN_AFTER_RESTART_S, 180)
        status = live.admin("status")
        world_metrics = _world_metrics(live)
        summary = live.wait_for(lambda: _summary_with_events(live), timeout_s=30)
        frames, truth = recorder.snapshot()

    assert recorder.undecodable == 0
    old, new, other = LEADER, 1, 2  # robot1 leads; robot2 is the lowest-index follower
    last_old_s = max(s.t_s for s in frames if s.sender == old and s.t_s < restart_seen_s)
    new_claims = [s for s in frames if s.sender == new and s.leads]
    first_new_s = new_claims[0].t_s
    takeover_s = first_new_s - last_old_s
    new_term = new_claims[0].term

    # Re-referenced formation after the kill.
    new_back = _first_time_under(truth, new, new, first_new_s)
    other_back = _first_time_under(truth, other, new, first_new_s)
    # The returning old leader, in robot2's old slot.
    returned = [s for s in frames if s.sender == old and s.t_s > last_old_s]
    old_back = _first_time_under(truth, old, new, returned[0].t_s if returned else math.inf)

    per_period: dict[int, set[int]] = {}
    for s in frames:
        if s.leads:
            per_period.setdefault(math.floor(s.t_s / BROADCAST_PERIOD_S + 1e-6), set()).add(
                s.sender
            )
    leaderless = [
        p * BROADCAST_PERIOD_S
        for p in range(min(per_period), max(per_period) + 1)
        if p not in per_period
    ]
    print(
        f"\nleader kill: robot1's last frame at {last_old_s:.2f} s, robot2's first leader frame "
        f"{takeover_s * 1000:.0f} ms later (term {new_term}); robot2 on the trajectory after "
        f"{_late(new_back, first_new_s)}, robot3 in its slot after {_late(other_back, first_new_s)}"
        f"; robot1 back at {returned[0].t_s if returned else None} s, in robot2's old slot after "
        f"{_late(old_back, returned[0].t_s if returned else 0.0)}; {len(frames)} frames checked, "
        f"{len(per_period)} broadcast periods with a leader, leaderless periods "
        f"{len(leaderless)} ({leaderless[:1]}..{leaderless[-1:]}); collisions "
        f"{world_metrics.get('collisions')}"
    )
    contacts = _contacts(truth)
    if contacts:
        episodes = [contacts[0]] + [
            c for before, c in itertools.pairwise(contacts) if c[0] - before[0] > 0.5
        ]
        print(f"contacts: {len(contacts)} truth samples, episodes starting at {episodes}")
    print(f"summary.json events: {summary['events']}")
    assert status["ok"]
    changes = [e for e in summary["events"] if e["kind"] == "leader_change"]
    assert [(e["from"], e["to"], e["term"]) for e in changes] == [
        (ROBOTS[old], ROBOTS[new], new_term)
    ]
    assert last_old_s < changes[0]["t_s"] <= first_new_s + 0.1
    assert 0.0 < takeover_s <= TAKEOVER_WITHIN_S
    assert new_term > 0
    assert new_back is not None and new_back - first_new_s <= FORMATION_WITHIN_S
    assert other_back is not None and other_back - first_new_s <= FORMATION_WITHIN_S
    # The old leader rejoins as a follower in robot2's term, and reaches robot2's old slot.
    assert returned and not any(s.leads for s in returned)
    assert {s.term for s in returned[-20:]} == {new_term}
    assert old_back is not None
    # Exactly one acting leader at every instant.
    assert all(len(leaders) == 1 for leaders in per_period.values()), per_period
    assert all(last_old_s < t_s < first_new_s for t_s in leaderless), leaderless
    claims = [s for s in frames if s.leads]
    assert [s.term for s in claims] == sorted(s.term for s in claims)
    leader_of_term: dict[int, set[int]] = {}
    for s in claims:
        leader_of_term.setdefault(s.term, set()).add(s.sender)
    assert all(len(v) == 1 for v in leader_of_term.values()), leader_of_term
    # No collision in the whole run: the dead leader's body, parked on the circle the new
    # leader flies, is gone round (robot_firmware/control/apf.py), and so is every robot a
    # rejoining one meets.
    assert world_metrics["collisions"] == 0, contacts


BODY_RADIUS_M = _SCENARIO.controller_params().body_radius_m


def _contacts(truth: list[dict[str, Any]]) -> list[tuple[float, str, float]]:
    """Truth instants at which two bodies overlap: (t_s, pair, gap_m)."""
    out = []
    for message in truth:
        poses = message["robots"]
        for a in range(len(ROBOTS)):
            for b in range(a + 1, len(ROBOTS)):
                pa, pb = poses[ROBOTS[a]]["pose"], poses[ROBOTS[b]]["pose"]
                gap_m = math.hypot(pa[0] - pb[0], pa[1] - pb[1]) - 2.0 * BODY_RADIUS_M
                if gap_m < 0.0:
                    out.append((round(message["t_s"], 2), f"{ROBOTS[a]}-{ROBOTS[b]}", gap_m))
    return out


def _summary_with_events(live: LiveSwarm) -> dict[str, Any] | None:
    """The world's summary.json once it records an event (it is rewritten every few seconds)."""
    path = live.out / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return summary if isinstance(summary, dict) and summary.get("events") else None


def _late(at_s: float | None, since_s: float) -> str:
    return "never" if at_s is None else f"{at_s - since_s:.1f} s"


def _world_metrics(live: LiveSwarm) -> dict[str, Any]:
    with open_client([live.endpoint]) as session:
        for reply in session.get(KEYS.admin("world", "status"), timeout=3.0):
            if reply.ok is not None:
                metrics = json.loads(reply.ok.payload.to_bytes()).get("metrics", {})
                return metrics if isinstance(metrics, dict) else {}
    return {}

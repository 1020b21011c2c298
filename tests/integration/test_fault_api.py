"""The fault API end to end: `swarm fault ...` against a lockstep swarm of real processes.

Each fault kind of swarm_config/faults.py is injected once through the command line a user
types.  The world, the one entry point of faults, applies it at a tick boundary and records a
`fault_injected` event in `<out>/events.jsonl` (the same event it answers with), and the swarm
behaves as docs/robustness.md says:

* register faults land in the robot's FPGA model: a stuck PWM's duty is on the act messages'
  pins, a forced watchdog expiry shows as an expired watchdog there, a sonar with no echo
  hears nothing (and the robot, hearing no peer it should, holds still), the robot's telemetry
  lists each active fault, and `clear-registers` ends them all;
* network faults: loss, latency and jitter on all links, one robot's or one link are
  recorded; a partition of robot3 stops every frame to it while robot2 still hears the
  others, and `heal` lets them through again;
* process faults: a killed follower goes down (`robot_down`) and rejoins the formation after
  `restart` (`robot_up`); a stopped one is down and shown stopped by the launcher, and `cont`
  brings it back without a restart; the world restarted resumes from its checkpoint
  (`world_resumed`); a frozen world is continued through the launcher; the router killed is
  started again by the launcher and the swarm carries on;
* an unknown process and a malformed fault are refused with a reason; a malformed one is
  refused before anything is sent, so nothing is recorded.

Collisions are counted after each phase and printed (pytest -s).  The goal is 0, asserted
around a follower's kill, restart, stop and cont and around the world's and the router's
faults; under several register faults at once on two robots (a saturated motor on a robot whose
sonar is deaf) no collision-free run is promised, so that count is only printed.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from robot_firmware.net.wire import ActMessage, decode_act
from swarm_config.faults import FAULT_ADAPTER, Fault, RunEvent
from swarm_config.scenario import load_scenario
from tests.integration.conftest import PAPER, LiveSwarm

pytestmark = pytest.mark.slow

SWARM = "lab"
KEYS = SwarmKeys(SWARM)
ROBOTS = load_scenario(PAPER).robot_names
FORMATION_BOUND_M = 0.05
LOCKSTEP = pytest.mark.parametrize(
    "live_swarm", [("--lockstep", "--max-speed", "2")], indirect=True
)


# -- talking to the swarm ----------------------------------------------------------------------


def _query(live: LiveSwarm, target: str, verb: str) -> dict[str, Any]:
    with open_client([live.endpoint]) as session:
        for reply in session.get(KEYS.admin(target, verb), timeout=3.0):
            if reply.ok is not None:
                data = json.loads(reply.ok.payload.to_bytes())
                return data if isinstance(data, dict) else {}
    return {}


def _world(live: LiveSwarm) -> dict[str, Any]:
    return _query(live, "world", "status")


def _metrics(live: LiveSwarm) -> dict[str, Any]:
    metrics = live.wait_for(lambda: _world(live).get("metrics"), describe="the world's metrics")
    assert isinstance(metrics, dict)
    return metrics


def _processes(live: LiveSwarm) -> dict[str, Any]:
    status = _query(live, "launcher", "status")
    processes = status.get("processes", {})
    return processes if isinstance(processes, dict) else {}


def _events(live: LiveSwarm) -> list[RunEvent]:
    try:
        lines = (live.out / "events.jsonl").read_bytes().splitlines(keepends=True)
    except OSError:
        return []
    # A last line without its newline is still being written.
    return [
        RunEvent.model_validate_json(line)
        for line in lines
        if line.strip() and line.endswith(b"\n")
    ]


def _fault(live: LiveSwarm, *argv: str, exit_code: int = 0) -> dict[str, Any]:
    """`swarm fault ARGV`: its exit status must be `exit_code`; its printed reply."""
    result = live.cli("fault", *argv)
    assert result.returncode == exit_code, (argv, result.stdout, result.stderr)
    if not result.stdout.strip():
        return {}
    reply = json.loads(result.stdout)
    assert isinstance(reply, dict)
    return reply


def _fault_json(fault: Fault) -> dict[str, Any]:
    data = FAULT_ADAPTER.dump_python(fault, mode="json", exclude_none=True)
    assert isinstance(data, dict)
    return data


def _inject(live: LiveSwarm, *argv: str) -> RunEvent:
    """`swarm fault ARGV` answered by the world: the `fault_injected` event it answers with,
    which is the one recorded in events.jsonl, carrying the fault the command line built."""
    dry = live.cli("fault", *argv, "--dry-run")
    assert dry.returncode == 0, dry.stderr
    fault = FAULT_ADAPTER.validate_json(dry.stdout)
    reply = _fault(live, *argv)
    assert reply.get("ok") is True, reply
    event = RunEvent.model_validate(reply["event"])
    assert event.kind == "fault_injected"
    assert event.detail["fault"] == _fault_json(fault)
    assert event.detail["source"] == "admin"
    live.wait_for(lambda: event in _events(live), timeout_s=10.0, describe=f"{argv} recorded")
    return event


def _event_after(
    live: LiveSwarm, kind: str, subject: str | None, after: RunEvent, timeout_s: float = 90.0
) -> RunEvent:
    """The first `kind` event about `subject` recorded after `after`."""

    def found() -> RunEvent | None:
        events = _events(live)
        if after not in events:
            return None
        later = events[events.index(after) + 1 :]
        return next((e for e in later if e.kind == kind and e.subject == subject), None)

    return live.wait_for(found, timeout_s=timeout_s, describe=f"{kind} {subject} after {after}")


def _ready(live: LiveSwarm) -> dict[str, Any]:
    """Every process running, every robot live and in its place; the world's status then."""
    live.wait_for(
        lambda: (p := _processes(live)) and all(c["running"] for c in p.values()),
        describe="every process running",
    )
    live.wait_for(lambda: len(_world(live).get("live", ())) == len(ROBOTS), describe="all live")
    ready: dict[str, Any] = live.wait_for(
        lambda: (
            (w := _world(live))
            and all(w["position_errors_m"][name] < FORMATION_BOUND_M for name in ROBOTS)
            and w
        ),
        timeout_s=180.0,
        describe="the formation in place",
    )
    print(f"\nthe formation in place at t = {ready['t_s']:.2f} s: {ready['position_errors_m']}")
    return ready


def _robot(live: LiveSwarm, name: str) -> dict[str, Any]:
    return live.wait_for(lambda: _query(live, name, "status"), describe=f"{name} answers")


class ActLog:
    """Every act message of one robot after the log started, in arrival order."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._acts: list[ActMessage] = []

    def on_sample(self, sample: zenoh.Sample) -> None:  # a zenoh callback: store and return
        act = decode_act(sample.payload.to_bytes())
        if act is not None:
            with self._lock:
                self._acts.append(act)

    def since(self, count: int) -> list[ActMessage]:
        with self._lock:
            return self._acts[count:]

    def __len__(self) -> int:
        with self._lock:
            return len(self._acts)


# -- register faults ----------------------------------------------------------------------------


@LOCKSTEP
def test_register_faults_land_in_the_fpga_model_and_clear(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    _ready(live)
    acts = ActLog()
    with open_client([live.endpoint]) as session:
        session.declare_subscriber(KEYS.act("robot2"), acts.on_sample)
        time.sleep(1.0)

        _inject(live, "pwm-stuck", "robot2", "--wheel", "0", "--duty", "0.37")
        before = len(acts)  # the fault is in the FPGA model once the world has answered
        held = live.wait_for(
            lambda: (a := acts.since(before)) and len(a) > 40 and a,
            describe="act messages after the stuck PWM",
        )
        stuck = [act.duty[0] for act in held[-30:]]
        print(f"\nrobot2 wheel 0 duty after pwm_stuck 0.37: {sorted(set(stuck))}")
        assert all(abs(duty - 0.37) < 0.01 for duty in stuck), stuck

        before = len(acts)
        _inject(live, "watchdog-expire", "robot2")
        live.wait_for(
            lambda: any(act.watchdog_expired for act in acts.since(before)),
            describe="an act message with the watchdog expired",
        )

        _inject(live, "sonar-no-echo", "robot3")
        live.wait_for(
            lambda: (
                (t := _query(live, "robot3", "status"))
                and t.get("sonar_range_m")
                and all(r is None for r in t["sonar_range_m"])
                and t["sonar_failed"]
            ),
            describe="robot3's sonar hearing nothing, taken as failed: robot3 holds still",
        )
        for argv in (
            ("encoder-stuck", "robot2", "--wheel", "1"),
            ("encoder-bit-stuck", "robot2", "--wheel", "2", "--bit", "6", "--value", "1"),
            ("pwm-saturated", "robot3", "--wheel", "3", "--sign", "-1"),
            ("fix-cut", "robot3"),
            ("tick-slow", "robot3", "--extra-ms", "3"),
        ):
            _inject(live, *argv)
        listed = {
            name: live.wait_for(
                lambda name=name, count=count: (
                    (t := _query(live, name, "status"))
                    and len(t.get("register_faults", ())) >= count
                    and t["register_faults"]
                ),
                describe=f"{name}'s telemetry naming its faults",
            )
            for name, count in (("robot2", 3), ("robot3", 4))
        }
        print(f"active register faults: {listed}")
        for name, expected in (
            ("robot2", ("pwm_stuck", "encoder_stuck", "encoder_bit_stuck")),
            ("robot3", ("sonar_no_echo", "pwm_saturated", "fix_cut", "tick_slow")),
        ):
            for fault in expected:
                assert any(label.startswith(fault) for label in listed[name]), (name, fault)

        for name in ("robot2", "robot3"):
            _inject(live, "clear-registers", name)
            live.wait_for(
                lambda name=name: (
                    (t := _query(live, name, "status"))
                    and "register_faults" in t
                    and not t["register_faults"]
                    and not t["sonar_failed"]
                ),
                describe=f"{name}'s faults cleared (and its sonar hearing again)",
            )
        assert _query(live, "robot3", "status")["sonar_failures"] == 1
        before = len(acts)
        freed = live.wait_for(
            lambda: (a := acts.since(before)) and len(a) > 40 and a,
            describe="act messages after clear-registers",
        )
        assert any(abs(act.duty[0] - 0.37) > 0.01 for act in freed[-30:])

    # A robot whose tick outlasts the lockstep answer time-out (2 s): the ticks go on without
    # its answers (excused) instead of waiting for it, and it is waited for again once cleared.
    _inject(live, "tick-slow", "robot2", "--extra-ms", "2500")
    slow = live.wait_for(
        lambda: (w := _world(live)) and w["lockstep_owed"]["robot2"]["excused"] >= 2 and w,
        describe="ticks that went on without robot2's late answers",
    )
    # The clearing waits for the next tick boundary (up to the 2 s answer time-out) and then
    # for robot2 to answer between two of its 2.5 s ticks (the world forwards it for up to
    # 5 s): more than the command's default 3 s.
    _inject(live, "clear-registers", "robot2", "--timeout", "15")
    cleared = _world(live)
    later = live.wait_for(
        lambda: (w := _world(live)) and w["t_s"] > cleared["t_s"] + 2.0 and w,
        describe="ticks after robot2's tick is fast again",
    )
    excused = [w["lockstep_owed"]["robot2"]["excused"] for w in (slow, cleared, later)]
    print(f"robot2 excused (slowed by 2.5 s, at its clearing, 2 s later): {excused}")
    assert (
        later["lockstep_owed"]["robot2"]["excused"] == cleared["lockstep_owed"]["robot2"]["excused"]
    )
    assert "robot2" in later["live"]
    assert all(later["lockstep_owed"][name]["excused"] == 0 for name in ("robot1", "robot3"))
    # A saturated or stuck motor is a physical fault: the swarm promises no collision-free run
    # under it (docs/robustness.md), so the count is reported, not bounded.
    print(f"collisions while the register faults were active: {_metrics(live)['collisions']}")


# -- network faults -----------------------------------------------------------------------------


def _accepted(live: LiveSwarm, robot: str) -> int:
    return int(_robot(live, robot)["frames"]["accepted"])


@LOCKSTEP
def test_network_faults_are_recorded_and_a_partition_stops_frames_until_heal(
    live_swarm: LiveSwarm,
) -> None:
    live = live_swarm
    _ready(live)
    _inject(live, "net", "--loss", "0.1")
    _inject(live, "net", "--robot", "robot3", "--latency-ms", "20")
    _inject(live, "net", "--link", "robot1,robot2", "--jitter-ms", "5")
    _inject(live, "net", "--link", "robot1,robot3", "--burst", "0.05,0.5")

    _inject(live, "partition", "robot3")
    time.sleep(2.0)  # frames already in flight are delivered or dropped
    cut_3, cut_2, cut_t = _accepted(live, "robot3"), _accepted(live, "robot2"), _world(live)["t_s"]
    live.wait_for(lambda: _world(live)["t_s"] > cut_t + 5.0, describe="5 s of simulation")
    after_3, after_2 = _accepted(live, "robot3"), _accepted(live, "robot2")
    print(
        f"\npartition of robot3 over {_world(live)['t_s'] - cut_t:.1f} s: robot3 accepted "
        f"{after_3 - cut_3} frames, robot2 {after_2 - cut_2}"
    )
    assert after_3 == cut_3
    assert after_2 > cut_2

    _inject(live, "heal")
    live.wait_for(
        lambda: _accepted(live, "robot3") > after_3, describe="robot3 hearing frames again"
    )
    live.wait_for(
        lambda: (
            (w := _world(live))
            and all(w["position_errors_m"][name] < FORMATION_BOUND_M for name in ROBOTS)
        ),
        timeout_s=180.0,
        describe="the formation back after heal",
    )


# -- process faults -----------------------------------------------------------------------------


@LOCKSTEP
def test_a_follower_killed_goes_down_and_rejoins_and_a_stopped_one_comes_back(
    live_swarm: LiveSwarm,
) -> None:
    live = live_swarm
    _ready(live)
    pid = _processes(live)["robot3"]["pid"]

    killed = _inject(live, "kill", "robot3")
    down = _event_after(live, "robot_down", "robot3", killed)
    assert "robot3" not in _world(live)["live"]
    assert not _processes(live)["robot3"]["running"]
    restarted = _inject(live, "restart", "robot3")
    up = _event_after(live, "robot_up", "robot3", restarted)
    live.wait_for(lambda: "robot3" in _world(live).get("live", ()), describe="robot3 live")
    back = live.wait_for(
        lambda: (w := _world(live)) and w["position_errors_m"]["robot3"] < FORMATION_BOUND_M and w,
        timeout_s=180.0,
        describe="robot3 back in its slot",
    )
    print(
        f"\nrobot3 killed at t = {killed.t_s:.2f} s, down at {down.t_s:.2f} s, restarted at "
        f"{restarted.t_s:.2f} s, up at {up.t_s:.2f} s, under 5 cm by t = {back['t_s']:.2f} s"
    )
    assert _processes(live)["robot3"]["pid"] != pid
    collisions = {"kill and restart": _metrics(live)["collisions"]}

    pid = _processes(live)["robot3"]["pid"]
    stopped = _inject(live, "stop", "robot3")
    _event_after(live, "robot_down", "robot3", stopped)
    process = _processes(live)["robot3"]
    assert process["stopped"] and process["running"]
    continued = _inject(live, "cont", "robot3")
    _event_after(live, "robot_up", "robot3", continued)
    process = _processes(live)["robot3"]
    assert not process["stopped"] and process["pid"] == pid
    live.wait_for(
        lambda: (w := _world(live)) and w["position_errors_m"]["robot3"] < FORMATION_BOUND_M,
        timeout_s=180.0,
        describe="robot3 back in its slot after cont",
    )
    collisions["stop and cont"] = _metrics(live)["collisions"]
    print(f"collisions so far, after each phase: {collisions}")
    assert collisions == {"kill and restart": 0, "stop and cont": 0}


@LOCKSTEP
def test_world_router_and_dashboard_faults(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    _ready(live)

    # The world restarted: recorded before it goes, resumed from its checkpoint.
    before_t = _world(live)["t_s"]
    reply = _fault(live, "restart", "world")
    recorded = live.wait_for(
        lambda: next(
            (
                e
                for e in _events(live)
                if e.kind == "fault_injected" and e.detail["fault"]["fault"] == "restart"
            ),
            None,
        ),
        describe="restart world recorded",
    )
    resumed = _event_after(live, "world_resumed", None, recorded)
    after = live.wait_for(lambda: _world(live), describe="the restarted world answering")
    print(
        f"\nworld restarted at t = {before_t:.2f} s (reply {sorted(reply)}); resumed at "
        f"t = {resumed.t_s:.2f} s, answering at t = {after['t_s']:.2f} s"
    )
    assert resumed.t_s >= recorded.t_s - 1.0
    assert _processes(live)["world"]["restarts"] == 1
    collisions = {"world restart": _metrics(live)["collisions"]}

    # The world stopped, then continued through the launcher (a frozen world cannot answer).
    _fault(live, "stop", "world")
    live.wait_for(lambda: _processes(live)["world"]["stopped"], describe="world stopped")
    assert not _world(live), "a stopped world answered"
    _fault(live, "cont", "world")
    moving = live.wait_for(lambda: _world(live), describe="the world answering after cont")
    live.wait_for(lambda: _world(live)["t_s"] > moving["t_s"] + 1.0, describe="time running again")
    assert _processes(live)["world"]["restarts"] == 1
    collisions["world stop and cont"] = _metrics(live)["collisions"]

    # The router killed: the launcher starts it again and the swarm carries on.
    restarts = _processes(live)["router"]["restarts"]
    result = live.cli("fault", "kill", "router")
    print(f"kill router: exit {result.returncode}, {result.stderr.strip()[-200:]}")
    live.wait_for(
        lambda: (p := _processes(live)) and p["router"]["restarts"] > restarts,
        describe="the router started again",
    )
    t_s = live.wait_for(lambda: _world(live), describe="the world through the new router")["t_s"]
    live.wait_for(lambda: _world(live)["t_s"] > t_s + 2.0, describe="ticks after the router")
    live.wait_for(lambda: len(_world(live)["live"]) == len(ROBOTS), describe="robots back")
    live.wait_for(
        lambda: (
            (w := _world(live))
            and all(w["position_errors_m"][name] < FORMATION_BOUND_M for name in ROBOTS)
        ),
        timeout_s=180.0,
        describe="the formation back after the router",
    )
    collisions["router kill"] = _metrics(live)["collisions"]
    print(f"collisions so far, after each phase: {collisions}")

    # No dashboard in this run: refused with the launcher's reason, and recorded as refused.
    refusal = _fault(live, "kill", "dashboard", exit_code=1)
    assert refusal["reason"] == "unknown_process", refusal
    live.wait_for(
        lambda: any(
            e.kind == "fault_refused" and e.detail.get("reason") == "unknown_process"
            for e in _events(live)
        ),
        describe="the refusal recorded",
    )

    # Malformed: refused before anything is sent.
    count = len(_events(live))
    _fault(live, "--json", '{"fault": "pwm_stuck", "robot": "robot2"}', exit_code=2)
    _fault(live, "tick-slow", "robot2", "--extra-ms", "-1", exit_code=2)
    time.sleep(1.0)
    assert len(_events(live)) == count

    assert collisions == {"world restart": 0, "world stop and cont": 0, "router kill": 0}
    # A router restart is no robot's death: every token went and came back while the world
    # held the tick (lockstep token grace), so no robot was down.
    injected = [e for e in _events(live) if e.kind == "fault_injected"]
    router_killed = next(
        e.t_s for e in injected if e.detail["fault"] == {"process": "router", "fault": "kill"}
    )
    assert not [e for e in _events(live) if e.kind == "robot_down" and e.t_s >= router_killed]
    assert _metrics(live)["collisions"] == 0

"""Killing the world of a live real-time swarm, and restarting it (DESIGN.md §7, §7.1).

Real processes under `swarm up` on a free port: the operator kills the world (`swarm kill
world`, a SIGKILL), every robot's PWM duty must be 0 within 200 ms of the world's last clock
message, read from the robots' own act messages; `swarm restart world` must resume from a
checkpoint at most 1 s of simulated time before the kill, under a new epoch, and the formation
must be back under 5 cm within 10 s of simulated time.  The figures are printed.

When the world was killed is known from outside only as the last clock message heard from it.
Where it resumed is its own `world_resumed` event, which must name the newest checkpoint the
killed world left on disk: the first clock messages of the restarted world may go out before
the router has its listener's route (under load, three ticks were missed), so the first one
heard is not where it resumed.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from robot_firmware.net.wire import ActMessage, ClockMessage, decode_act, decode_clock
from swarm_config.faults import RunEvent
from swarm_config.scenario import load_scenario
from tests.integration.conftest import PAPER, LiveSwarm

pytestmark = pytest.mark.slow

SWARM = "lab"
KEYS = SwarmKeys(SWARM)
_SCENARIO = load_scenario(PAPER)
ROBOTS = _SCENARIO.robot_names
FOLLOWERS = tuple(
    name for name, spec in zip(ROBOTS, _SCENARIO.robots, strict=True) if spec.role != "leader"
)
MOTORS_OFF_WITHIN_S = 0.2
RESUME_AT_MOST_S_BEFORE_KILL = 1.0
FORMATION_BOUND_M = 0.05
FORMATION_BACK_WITHIN_S = 10.0
STEADY_FLIGHT_S = 10.0


@dataclass
class Heard:
    """Every clock and act message while open, with its arrival time (monotonic seconds)."""

    clocks: list[tuple[float, ClockMessage]] = field(default_factory=list)
    acts: list[tuple[float, str, ActMessage]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_clock(self, sample: zenoh.Sample) -> None:  # zenoh callbacks: store and return
        clock = decode_clock(sample.payload.to_bytes())
        if clock is not None:
            with self.lock:
                self.clocks.append((time.monotonic(), clock))

    def on_act(self, sample: zenoh.Sample) -> None:
        act = decode_act(sample.payload.to_bytes())
        if act is not None:
            robot = SwarmKeys.chunk(str(sample.key_expr), 3)
            with self.lock:
                self.acts.append((time.monotonic(), robot, act))

    def snapshot(
        self,
    ) -> tuple[list[tuple[float, ClockMessage]], list[tuple[float, str, ActMessage]]]:
        with self.lock:
            return list(self.clocks), list(self.acts)


@contextmanager
def _listening(live_swarm: LiveSwarm) -> Iterator[tuple[Heard, zenoh.Session]]:
    heard = Heard()
    with open_client([live_swarm.endpoint]) as session:
        subscribers = [
            session.declare_subscriber(KEYS.clock, heard.on_clock),
            session.declare_subscriber(KEYS.act_all, heard.on_act),
        ]
        try:
            yield heard, session
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()


def _world_status(session: zenoh.Session) -> dict[str, Any]:
    """The world's status reply, or {} when no world answers."""
    for reply in session.get(KEYS.admin("world", "status"), timeout=2.0):
        if reply.ok is not None:
            data = json.loads(reply.ok.payload.to_bytes())
            return data if isinstance(data, dict) else {}
    return {}


def _formation_error_m(status: dict[str, Any]) -> float | None:
    if not status or set(status.get("live", ())) != set(ROBOTS):
        return None
    return max(status["position_errors_m"][name] for name in FOLLOWERS)


def _newest_checkpoint_tick(live_swarm: LiveSwarm) -> int:
    """The tick of the newest checkpoint on disk (`world-<tick>.ckpt`, world/checkpoint.py)."""
    names = (live_swarm.out / "checkpoints").glob("world-*.ckpt")
    return max(int(path.stem.removeprefix("world-")) for path in names)


def _world_resumed(live_swarm: LiveSwarm) -> RunEvent | None:
    """The newest `world_resumed` event in events.jsonl (whole lines only)."""
    try:
        lines = (live_swarm.out / "events.jsonl").read_bytes().splitlines(keepends=True)
    except OSError:
        return None
    events = [RunEvent.model_validate_json(line) for line in lines if line.endswith(b"\n")]
    return next((e for e in reversed(events) if e.kind == "world_resumed"), None)


def _is_off(act: ActMessage) -> bool:
    return all(d == 0.0 for d in act.duty) or not any(act.enabled)


def test_killed_world_stops_every_robot_and_a_restarted_one_resumes_its_checkpoint(
    live_swarm: LiveSwarm,
) -> None:
    with _listening(live_swarm) as (heard, session):
        # A real-time swarm flying its formation, well under way.
        live_swarm.wait_for(
            lambda: (
                (s := _world_status(session)).get("t_s", 0.0) >= STEADY_FLIGHT_S
                and (e := _formation_error_m(s)) is not None
                and e < FORMATION_BOUND_M
            ),
            timeout_s=120.0,
            describe="the formation under 5 cm before the kill",
        )
        live_swarm.wait_for(
            lambda: any(
                p.name.endswith(".ckpt") for p in (live_swarm.out / "checkpoints").iterdir()
            ),
            describe="a checkpoint on disk",
        )
        old_epoch = heard.snapshot()[0][-1][1].epoch

        assert live_swarm.admin("kill", "world")["killed"]
        time.sleep(1.5)  # the world stays down: robots only extrapolate time, and must stop
        clocks, acts = heard.snapshot()
        last_wall_s, last_clock = clocks[-1]
        killed_at_sim_s = last_clock.t_ns / 1e9
        off_after_s: dict[str, float | None] = {}
        driving_at_kill = {}
        for name in ROBOTS:
            own = [(t, a) for t, r, a in acts if r == name]
            before = [a for t, a in own if t <= last_wall_s]
            driving_at_kill[name] = bool(before) and not _is_off(before[-1])
            after = [(t, a) for t, a in own if t > last_wall_s]
            first_off = next((t for t, a in after if _is_off(a)), None)
            off_after_s[name] = None if first_off is None else first_off - last_wall_s
            # Once off, it stays off while no world runs.
            if first_off is not None:
                assert all(_is_off(a) for t, a in after if t >= first_off), name
        print(
            f"\nworld killed at t = {killed_at_sim_s:.3f} s; robots driving then: "
            f"{driving_at_kill}; PWM duty 0 after the world's last clock message: "
            + ", ".join(
                f"{n} {'never' if s is None else f'{s * 1000:.0f} ms'}"
                for n, s in off_after_s.items()
            )
        )

        newest_tick = _newest_checkpoint_tick(live_swarm)
        restart = live_swarm.admin("restart", "world")
        assert restart.get("restarted") == "world", restart
        resumed = live_swarm.wait_for(
            lambda: next((c for _, c in heard.snapshot()[0] if c.epoch != old_epoch), None),
            timeout_s=60.0,
            describe="a clock message of the restarted world",
        )
        resume = live_swarm.wait_for(lambda: _world_resumed(live_swarm), timeout_s=30.0)
        resumed_at_sim_s = resume.t_s
        formation_back: dict[str, float] = {}

        def formation_back_under_bound() -> bool:
            status = _world_status(session)
            error = _formation_error_m(status)
            if error is None or error >= FORMATION_BOUND_M:
                return False
            formation_back["t_s"] = status["t_s"]
            formation_back["error_m"] = error
            return True

        live_swarm.wait_for(
            formation_back_under_bound,
            timeout_s=120.0,
            every_s=0.1,
            describe="the formation under 5 cm after the restart",
        )
        back_after_s = formation_back["t_s"] - resumed_at_sim_s
        status = _world_status(session)
        print(
            f"world restarted: resumed at t = {resumed_at_sim_s:.3f} s "
            f"({killed_at_sim_s - resumed_at_sim_s:.3f} s before the kill), new epoch "
            f"{resumed.epoch != old_epoch}; formation under 5 cm after {back_after_s:.2f} s "
            f"(max follower error {formation_back['error_m'] * 100:.1f} cm); collisions "
            f"{status['metrics']['collisions']}"
        )

    world_log = (live_swarm.out / "logs" / "world.log").read_text()
    assert "resuming from checkpoint" in world_log, world_log[-2000:]
    assert resume.detail["tick"] == newest_tick
    assert resumed_at_sim_s > 0.0
    assert killed_at_sim_s - resumed_at_sim_s <= RESUME_AT_MOST_S_BEFORE_KILL
    assert back_after_s <= FORMATION_BACK_WITHIN_S
    assert status["metrics"]["collisions"] == 0, status["metrics"]
    for name, delay_s in off_after_s.items():
        assert delay_s is not None and delay_s <= MOTORS_OFF_WITHIN_S, (name, delay_s)


@pytest.mark.parametrize("live_swarm", [("--lockstep",)], indirect=True)
def test_lockstep_world_restarted_resumes_its_checkpoint_and_the_robots_answer_it(
    live_swarm: LiveSwarm,
) -> None:
    with _listening(live_swarm) as (heard, session):
        live_swarm.wait_for(
            lambda: (
                (s := _world_status(session)).get("t_s", 0.0) >= STEADY_FLIGHT_S
                and (e := _formation_error_m(s)) is not None
                and e < FORMATION_BOUND_M
            ),
            timeout_s=120.0,
            describe="the formation under 5 cm before the kill",
        )
        assert _world_status(session)["clock_mode"] == "lockstep"
        old_epoch = heard.snapshot()[0][-1][1].epoch
        assert live_swarm.admin("kill", "world")["killed"]
        time.sleep(0.5)
        killed_at_sim_s = heard.snapshot()[0][-1][1].t_ns / 1e9
        newest_tick = _newest_checkpoint_tick(live_swarm)
        restart = live_swarm.admin("restart", "world")
        assert restart.get("restarted") == "world", restart
        live_swarm.wait_for(
            lambda: next((c for _, c in heard.snapshot()[0] if c.epoch != old_epoch), None),
            timeout_s=60.0,
            describe="a clock message of the restarted world",
        )
        resume = live_swarm.wait_for(lambda: _world_resumed(live_swarm), timeout_s=30.0)
        resumed_at_sim_s = resume.t_s
        formation_back: dict[str, float] = {}

        def formation_back_under_bound() -> bool:
            status = _world_status(session)
            error = _formation_error_m(status)
            if error is None or error >= FORMATION_BOUND_M:
                return False
            formation_back.update(t_s=status["t_s"], error_m=error)
            return True

        live_swarm.wait_for(formation_back_under_bound, timeout_s=120.0, every_s=0.1)
        # Every robot answers the resumed world's ticks: time goes on past the kill.
        live_swarm.wait_for(
            lambda: _world_status(session).get("t_s", 0.0) > killed_at_sim_s + 2.0,
            describe="the resumed lockstep world past the kill",
        )
        status = _world_status(session)
        back_after_s = formation_back["t_s"] - resumed_at_sim_s
        print(
            f"\nlockstep world killed at t = {killed_at_sim_s:.3f} s, resumed at "
            f"t = {resumed_at_sim_s:.3f} s ({killed_at_sim_s - resumed_at_sim_s:.3f} s before); "
            f"formation under 5 cm {back_after_s:.2f} s after the resume "
            f"(max follower error {formation_back['error_m'] * 100:.1f} cm); collisions "
            f"{status['metrics']['collisions']}; live {status['live']}"
        )
    assert sorted(status["live"]) == sorted(ROBOTS)
    assert resume.detail["tick"] == newest_tick
    assert resumed_at_sim_s > 0.0
    assert killed_at_sim_s - resumed_at_sim_s <= RESUME_AT_MOST_S_BEFORE_KILL
    assert back_after_s <= FORMATION_BACK_WITHIN_S
    assert status["metrics"]["collisions"] == 0, status["metrics"]

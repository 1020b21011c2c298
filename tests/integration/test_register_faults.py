"""Register faults through Zenoh into a running robot process (lockstep swarm of real processes).

The operator asks robot2's `fault` admin verb directly (the world's `fault` verb forwards the
same JSON).  What the robot's FPGA model then puts on its motor pins is read where the world
reads it, in robot2's act messages: a stuck PWM holds its duty whatever the firmware commands,
a forced watchdog expiry cuts one act message and the next tick re-arms the watchdog, a refused
fault changes nothing, and `clear_registers` gives the wheel back to the firmware.
"""

from __future__ import annotations

import json
import threading
from typing import Any

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import open_client
from robot_firmware.net.wire import ActMessage, decode_act
from swarm_config.scenario import load_scenario
from tests.integration.conftest import PAPER, LiveSwarm

pytestmark = pytest.mark.slow

SWARM = "lab"
ROBOTS = load_scenario(PAPER).robot_names
VICTIM = "robot2"
STUCK_DUTY = 0.37
HELD_ACTS = 50


class ActLog:
    """Every act message of one robot, in arrival order."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._acts: list[ActMessage] = []

    def on_sample(self, sample: zenoh.Sample) -> None:  # a zenoh callback: store and return
        act = decode_act(sample.payload.to_bytes())
        if act is not None:
            with self._lock:
                self._acts.append(act)

    def acts(self) -> list[ActMessage]:
        with self._lock:
            return list(self._acts)


def _ask(session: zenoh.Session, target: str, verb: str, body: object = None) -> dict[str, Any]:
    payload = None if body is None else json.dumps(body).encode()
    for reply in session.get(SwarmKeys(SWARM).admin(target, verb), payload=payload, timeout=5.0):
        if reply.ok is not None:
            data = json.loads(reply.ok.payload.to_bytes())
            return data if isinstance(data, dict) else {}
    return {}


def _fault(session: zenoh.Session, fault: str, **fields: object) -> dict[str, Any]:
    return _ask(session, VICTIM, "fault", {"fault": fault, "robot": VICTIM, **fields})


@pytest.mark.parametrize("live_swarm", [("--lockstep",)], indirect=True)
def test_register_faults_reach_the_motor_pins_of_a_running_robot(live_swarm: LiveSwarm) -> None:
    live = live_swarm
    log = ActLog()
    with open_client([live.endpoint]) as session:
        session.declare_subscriber(SwarmKeys(SWARM).act(VICTIM), log.on_sample)
        live.wait_for(
            lambda: len(_ask(session, "world", "status").get("live", ())) == len(ROBOTS),
            describe="every robot live",
        )
        live.wait_for(lambda: len(log.acts()) > 100, describe=f"{VICTIM} acting")
        assert _ask(session, VICTIM, "fault") == {"ok": True, "robot": VICTIM, "active": []}

        before_stuck = len(log.acts())
        stuck = _fault(session, "pwm_stuck", wheel=0, duty=STUCK_DUTY)
        assert stuck["ok"] and [f["fault"] for f in stuck["active"]] == ["pwm_stuck"]
        live.wait_for(lambda: len(log.acts()) > before_stuck + HELD_ACTS + 2)
        after = log.acts()[before_stuck:]
        first_held = next(i for i, a in enumerate(after) if a.duty[0] == STUCK_DUTY)
        held = after[first_held:]
        assert all(a.duty[0] == STUCK_DUTY and a.enabled[0] for a in held)
        assert any(a.duty[1] != 0.0 for a in held)  # the firmware drives the other wheels

        assert _fault(session, "fix_cut")["ok"]
        refused = _ask(session, VICTIM, "fault", {"fault": "fix_cut", "robot": "robot1"})
        assert refused["ok"] is False and refused["reason"] == "unknown_robot"
        listed = _ask(session, VICTIM, "fault")
        assert [f["fault"] for f in listed["active"]] == ["pwm_stuck", "fix_cut"]

        before_expiry = len(log.acts())
        expiry = _fault(session, "watchdog_expire")
        assert [f["fault"] for f in expiry["active"]][-1] == "watchdog_expire"
        live.wait_for(lambda: len(log.acts()) > before_expiry + 20)
        around = log.acts()[before_expiry:]
        cut = [i for i, a in enumerate(around) if a.watchdog_expired]
        assert len(cut) == 1, cut
        assert around[cut[0]].duty == (0.0,) * 4
        assert not around[cut[0] + 1].watchdog_expired
        assert around[cut[0] + 1].duty[0] == STUCK_DUTY

        telemetry = _ask(session, VICTIM, "status")
        assert telemetry["register_faults"] == [f"pwm_stuck(wheel=0, duty={STUCK_DUTY})", "fix_cut"]

        before_clear = len(log.acts())
        cleared = _fault(session, "clear_registers")
        assert cleared["active"] == []
        live.wait_for(lambda: len(log.acts()) > before_clear + 20)
        freed = log.acts()[before_clear + 2 :]
        assert any(a.duty[0] != STUCK_DUTY for a in freed)
        print(
            f"\n{VICTIM}: the stuck duty {STUCK_DUTY} was on wheel 0 from the act message "
            f"{first_held} after the fault's reply on, in {len(held)} act messages in a row; "
            f"the forced expiry cut act message {cut[0]} after its reply, the next one drove "
            "again"
        )

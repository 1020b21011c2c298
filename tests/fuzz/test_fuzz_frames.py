"""Fuzzing radio frames where a robot receives them: the firmware's `receive` (the frame decoder
of robot_firmware/net/frames.py in front of the peer table).

A follower gets 10,000 inputs: random bytes, mutants of the frames the leader and the other
follower really broadcast (bits flipped, fields overwritten, cut, extended), replays of older
frames, and frames re-signed with the swarm's key after a field was changed (time far back or
ahead, sequence repeated, behind or far ahead, a non-finite or implausible pose, the robot's
own id, a sender the scenario does not have).  A twin follower gets only the frames the first
one's decoder accepted.  After every batch all robots run a control tick: the two followers'
act messages, register files, wheel commands and broadcasts must be identical, and every
refused frame must be counted under its `DropReason`.

This file uses only the decoder's public API and frames the firmware itself makes, so it runs
against whatever frame layout frames.py has.
"""

from __future__ import annotations

import dataclasses
import random

from robot_firmware.net.frames import FRAME_BYTES, DropReason, RadioFrame, encode, parse_frame
from robot_firmware.net.wire import FixSample, SenseMessage, encode_sense
from tests.fuzz.generate import mutate_bytes, random_bytes
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.processes import Robot, assert_same_actuation, make_robot

INPUTS = 10_000
BATCH = 50
UNKNOWN_SENDER = "accepted_from_unknown_sender"
"""Authentic frames whose sender id is no robot of the scenario: the decoder accepts them, the
firmware leaves its peer table alone (and counts them nowhere)."""
GENUINE = "radio frame: genuine broadcasts"
"""The real broadcasts of the other robots, heard between the fuzzed frames."""


def resigned(rng: random.Random, frame: RadioFrame, key: bytes, own_id: int) -> bytes:
    """`frame` with one field changed, signed again with the swarm's key."""
    second_ns = 1_000_000_000
    change = rng.randrange(10)
    if change == 0:
        update = {"timestamp_ns": max(0, frame.timestamp_ns - rng.choice((2, 5, 100)) * second_ns)}
    elif change == 1:
        update = {"timestamp_ns": frame.timestamp_ns + rng.choice((2, 60)) * second_ns}
    elif change == 2:
        update = {"sequence": (frame.sequence - rng.randint(0, 3)) % 2**32}
    elif change == 3:
        update = {"sequence": (frame.sequence + rng.choice((2**20, 2**31, 2**31 + 5))) % 2**32}
    elif change == 4:
        field = rng.choice(("x_m", "y_m", "theta_rad", "xdot_mps", "ydot_mps", "thetadot_radps"))
        update = {field: rng.choice((float("nan"), float("inf"), -float("inf")))}
    elif change == 5:
        update = {
            rng.choice(("x_m", "y_m")): rng.choice((1e5, -2e4)),
            "sequence": frame.sequence + 1,
        }
    elif change == 6:
        update = {"xdot_mps": 500.0, "sequence": (frame.sequence + 1) % 2**32}
    elif change == 7:
        update = {"sender_id": rng.choice((own_id, 50, 65535))}
    elif change == 8:
        update = {"localised": not frame.localised}
    else:  # a plausible next state: accepted
        update = {
            "sequence": (frame.sequence + 1) % 2**32,
            "timestamp_ns": frame.timestamp_ns + 1_000_000,
            "x_m": frame.x_m + 0.01,
        }
    return encode(dataclasses.replace(frame, **update), key)


def fuzzed(rng: random.Random, recent: list[bytes], key: bytes, own_id: int) -> bytes:
    roll = rng.random()
    latest = recent[-1]
    if roll < 0.25:
        return random_bytes(rng, 2 * FRAME_BYTES)
    if roll < 0.6:
        return mutate_bytes(rng, latest, tuple(range(20, FRAME_BYTES - 8, 8)))
    if roll < 0.75:
        return rng.choice(recent)  # a replay
    parsed = parse_frame(latest, key)
    assert isinstance(parsed, RadioFrame)
    return resigned(rng, parsed, key, own_id)


def test_no_radio_frame_a_robot_refuses_moves_it() -> None:
    senders = make_robot("robot1"), make_robot("robot3")  # the leader and the other follower
    fed_everything, fed_valid_only = make_robot("robot2"), make_robot("robot2")
    followers = fed_everything, fed_valid_only
    firmware = fed_everything.process.firmware
    key = firmware._key
    own_id = firmware.mission.index
    period_ns = fed_everything.process.period_ns
    rng = random.Random(20240614)
    target = "radio frame -> robot"
    recent: list[bytes] = []
    warm_up = 0
    tick = 0
    while not recent or tick < 2 * BATCH:  # a second of flight before the fuzzing starts
        tick += 1
        heard = _tick(senders, tick * period_ns)
        for robot in followers:
            for frame in heard:
                assert robot.process.firmware.receive(frame, tick * period_ns)
            robot.control_tick(tick * period_ns)
        warm_up += len(heard)
        recent = (recent + heard)[-40:]
    for _batch in range(INPUTS // BATCH):
        tick += 1
        now_ns = tick * period_ns
        heard = _tick(senders, now_ns)
        for frame in heard:
            # A genuine broadcast is refused after an authentic frame with a sequence far
            # ahead was accepted (an insider's, or a replay across a reboot): counted apart.
            accepted = firmware.receive(frame, now_ns)
            assert fed_valid_only.process.firmware.receive(frame, now_ns) == accepted
            outcome = firmware.decoder.last_drop_reason
            LEDGER.record(GENUINE, ACCEPTED if outcome is None else outcome)
        recent = (recent + heard)[-40:]
        for _ in range(BATCH):
            data = fuzzed(rng, recent, key, own_id)
            in_peer_table = firmware.receive(data, now_ns)
            reason = firmware.decoder.last_drop_reason
            if reason is None:
                assert fed_valid_only.process.firmware.receive(data, now_ns) == in_peer_table
                LEDGER.record(target, ACCEPTED if in_peer_table else UNKNOWN_SENDER)
            else:
                assert isinstance(reason, DropReason) and not in_peer_table
                LEDGER.record(target, reason)
        for robot in followers:
            robot.control_tick(now_ns)
        assert_same_actuation(fed_everything, fed_valid_only)
    counters = firmware.decoder.counters
    outcomes = LEDGER.outcomes[target]
    genuine = LEDGER.outcomes[GENUINE]
    fuzz_and_genuine = outcomes + genuine
    assert {r.value: n for r, n in counters.dropped.items() if n} == {
        r: n for r, n in fuzz_and_genuine.items() if r not in (ACCEPTED, UNKNOWN_SENDER)
    }
    assert counters.accepted == warm_up + fuzz_and_genuine[ACCEPTED] + outcomes[UNKNOWN_SENDER]
    assert counters.dropped_total > INPUTS // 2
    assert outcomes[ACCEPTED] > 0


def _tick(senders: tuple[Robot, ...], now_ns: int) -> list[bytes]:
    """One control tick of every sender, each given a positioning fix first (a robot
    broadcasts only once it is localised); the frames they broadcast in it."""
    heard = []
    for robot in senders:
        mission = robot.process.mission
        fix = FixSample(float(mission.index), 0.0, 0.0, now_ns)
        robot.sense(
            encode_sense(
                SenseMessage((0, 0, 0, 0), (None,) * mission.sonar_count, fix, t_ns=now_ns)
            )
        )
        sent = len(robot.radio.payloads)
        robot.control_tick(now_ns)
        heard += robot.radio.payloads[sent:]
    return heard

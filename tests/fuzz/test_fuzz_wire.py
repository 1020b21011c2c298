"""Fuzzing the pin-level wire messages (robot_firmware/net/wire.py) where they are received.

* sense: every input goes through a real robot process's `_take_sense` (the path from the
  `wire/<robot>/sense` subscriber to the pins); a twin robot gets only the inputs the first
  one accepted, and after every batch both run a control tick: their act messages, register
  files, wheel commands and radio broadcasts must be identical, so no refused input moved a
  robot.  The robot's telemetry must count every refusal under its reason.
* act: every input goes through a real world process's `_drain` on the key of a robot (or of
  a name the scenario does not know); the duty table, the lockstep barrier and the act times
  must equal a twin world's fed only the accepted inputs, and summary.json must count every
  refusal under its reason.
* clock: the decoder alone (no process consumes the clock yet).

10,000 inputs per message kind come from seeded generators (tests/fuzz/generate.py); the
hypothesis tests add shrinking on fewer examples.
"""

from __future__ import annotations

import random
import struct

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robot_firmware.net.wire import (
    MAX_ABS_FIX_M,
    MAX_ECHO_TIME_S,
    ActMessage,
    ClockMessage,
    FixSample,
    SenseMessage,
    WireCounters,
    WireDropReason,
    encode_act,
    encode_clock,
    encode_sense,
    parse_act,
    parse_clock,
    parse_sense,
)
from tests.fuzz.generate import mutate_bytes, random_bytes
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.mutation import random_or_mutant
from tests.fuzz.processes import assert_same_actuation, make_robot, make_world

INPUTS = 10_000
BATCH = 50
"""Inputs fed between two control ticks."""
HYPOTHESIS = settings(
    max_examples=400,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

SENSE_DOUBLES = (52, 60, 68)
"""Offsets of the fix's x_m, y_m, heading_rad."""
SENSE_ECHOES_AT = 84
ACT_DOUBLES = (12, 20, 28, 36)


def world_sense(rng: random.Random, sonar_count: int, tick: int, t_ns: int) -> bytes:
    """A sense message as the world sends it."""
    fix = None
    if rng.random() < 0.3:
        fix = FixSample(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-7, 7), t_ns)
    return encode_sense(
        SenseMessage(
            encoder_counts=tuple(tick * 40 + rng.randint(-5, 5) for _ in range(4)),
            sonar_echo_times_s=tuple(
                None if rng.random() < 0.5 else rng.uniform(0.0, 0.025) for _ in range(sonar_count)
            ),
            fix=fix,
            tick=tick,
            t_ns=t_ns,
            radio_frames=rng.randint(0, 2),
        )
    )


def robot_act(rng: random.Random, tick: int) -> bytes:
    return encode_act(
        ActMessage(
            tick=tick,
            duty=(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)),
            enabled=(True, True, rng.random() < 0.9, True),
            watchdog_expired=rng.random() < 0.05,
            radio_frames=rng.randint(0, 1),
        )
    )


def fuzzed(
    rng: random.Random, valid: bytes, doubles: tuple[int, ...], singles: tuple[int, ...] = ()
) -> bytes:
    """Random bytes, a mutant of `valid`, or `valid` itself."""
    roll = rng.random()
    if roll < 0.3:
        return random_bytes(rng, 2 * len(valid))
    if roll < 0.95:
        return mutate_bytes(rng, valid, doubles, singles)
    return valid


def check_sense(message: SenseMessage | WireDropReason, sonar_count: int) -> None:
    """An accepted sense message holds only what a world can send, and survives a round trip."""
    if isinstance(message, WireDropReason):
        return
    assert len(message.encoder_counts) == 4
    assert len(message.sonar_echo_times_s) == sonar_count
    for t in message.sonar_echo_times_s:
        assert t is None or 0.0 <= t <= MAX_ECHO_TIME_S
    if message.fix is not None:
        assert abs(message.fix.x_m) <= MAX_ABS_FIX_M and abs(message.fix.y_m) <= MAX_ABS_FIX_M
        assert np.isfinite(message.fix.heading_rad)
    assert parse_sense(encode_sense(message), sonar_count) == message


def check_act(message: ActMessage | WireDropReason) -> None:
    if isinstance(message, WireDropReason):
        return
    assert all(-1.0 <= d <= 1.0 for d in message.duty)
    assert parse_act(encode_act(message)) == message


def test_no_sense_message_a_robot_refuses_moves_it() -> None:
    fed_everything, fed_valid_only = make_robot(), make_robot()
    robot = fed_everything.process
    sonar_count = robot.mission.sonar_count
    period_ns = robot.period_ns
    rng = random.Random(20240611)
    target = "wire.sense -> robot"
    refused = WireCounters()
    for batch in range(INPUTS // BATCH):
        tick, now_ns = batch + 1, (batch + 1) * period_ns
        valid = world_sense(rng, sonar_count, tick, now_ns)
        fed_everything.sense(valid)
        fed_valid_only.sense(valid)
        for _ in range(BATCH):
            if rng.random() < 0.02:  # a world configured with another sonar ring
                data = world_sense(rng, rng.choice((0, 1, sonar_count + 1, 64)), tick, now_ns)
            else:
                echoes_at = tuple(range(SENSE_ECHOES_AT, len(valid), 4))
                data = fuzzed(rng, valid, SENSE_DOUBLES, echoes_at)
            before = dict(robot.sense_counters.dropped)
            fed_everything.sense(data)
            outcome = parse_sense(data, sonar_count)
            check_sense(outcome, sonar_count)
            changed = [r for r, n in robot.sense_counters.dropped.items() if n != before[r]]
            if isinstance(outcome, WireDropReason):
                assert changed == [outcome], (data, outcome, changed)
            else:
                assert changed == []
                fed_valid_only.sense(data)
            refused.count(outcome)
            LEDGER.record(target, ACCEPTED if changed == [] else outcome)
        fed_everything.control_tick(now_ns)
        fed_valid_only.control_tick(now_ns)
        assert_same_actuation(fed_everything, fed_valid_only)
    telemetry = robot.telemetry(INPUTS * period_ns)
    assert telemetry.dropped_sense == refused.dropped_as_dict()
    assert telemetry.malformed_sense == refused.dropped_total == LEDGER.rejected(target)
    assert refused.dropped_total > INPUTS // 2
    assert refused.accepted > INPUTS // 50


def test_no_act_message_the_world_refuses_changes_a_duty() -> None:
    fed_everything, fed_valid_only = make_world(), make_world()
    names = fed_everything.names
    for world in (fed_everything, fed_valid_only):
        for name in names:
            world.barrier.join(name)
        world.barrier.start()
    rng = random.Random(20240612)
    target = "wire.act -> world"
    refused = WireCounters()
    valid = robot_act(rng, 0)
    for i in range(INPUTS):
        if i % BATCH == 0:
            valid = robot_act(rng, i // BATCH)
        robot = rng.choice(names) if rng.random() < 0.9 else rng.choice(("robot9", "world", ""))
        data = fuzzed(rng, valid, ACT_DOUBLES)
        arrival_ns = 1_000 + i
        before = dict(fed_everything.act_counters.dropped)
        fed_everything._acts.put((robot, data, arrival_ns))
        fed_everything._drain()
        outcome = parse_act(data) if robot in names else WireDropReason.UNKNOWN_ROBOT
        check_act(outcome)
        changed = [r for r, n in fed_everything.act_counters.dropped.items() if n != before[r]]
        if isinstance(outcome, WireDropReason):
            assert changed == [outcome], (robot, data, outcome, changed)
        else:
            assert changed == []
            fed_valid_only._acts.put((robot, data, arrival_ns))
            fed_valid_only._drain()
        refused.count(outcome)
        LEDGER.record(target, outcome if isinstance(outcome, WireDropReason) else ACCEPTED)
        if i % BATCH == BATCH - 1:
            assert np.array_equal(fed_everything.duty, fed_valid_only.duty)
            assert np.array_equal(fed_everything.act_seen_mono_ns, fed_valid_only.act_seen_mono_ns)
            assert fed_everything.barrier.seats == fed_valid_only.barrier.seats
    summary = fed_everything.summary()
    assert summary["dropped_inputs"]["act"] == refused.dropped_as_dict()  # type: ignore[index]
    assert summary["malformed_acts"] == refused.dropped_total == LEDGER.rejected(target)
    assert refused.dropped[WireDropReason.UNKNOWN_ROBOT] > 0
    assert refused.accepted > INPUTS // 50


def test_clock_decoder_refuses_every_malformed_message_by_name() -> None:
    rng = random.Random(20240613)
    refused = WireCounters()
    for i in range(INPUTS):
        valid = encode_clock(ClockMessage(i, i * 10_000_000, 10_000_000, rng.random() < 0.5))
        data = fuzzed(rng, valid, ())
        outcome = parse_clock(data)
        if isinstance(outcome, ClockMessage):
            assert outcome.dt_ns > 0
            assert parse_clock(encode_clock(outcome)) == outcome
        refused.count(outcome)
        LEDGER.record("wire.clock", outcome if isinstance(outcome, WireDropReason) else ACCEPTED)
    assert refused.accepted + refused.dropped_total == INPUTS
    assert refused.dropped_total > INPUTS // 2


# -- hypothesis: the decoders alone, with shrinking ---------------------------------------------

_sense_messages = st.builds(
    SenseMessage,
    encoder_counts=st.tuples(*[st.integers(-(2**63), 2**63 - 1)] * 4),
    sonar_echo_times_s=st.lists(
        st.none() | st.floats(0.0, 0.0625, width=32), min_size=12, max_size=12
    ).map(tuple),
    fix=st.none()
    | st.builds(
        FixSample,
        st.floats(-5, 5),
        st.floats(-5, 5),
        st.floats(-7, 7),
        st.integers(0, 2**64 - 1),
        st.booleans(),
    ),
    tick=st.integers(0, 2**64 - 1),
    t_ns=st.integers(0, 2**64 - 1),
    lockstep=st.booleans(),
    radio_frames=st.integers(0, 255),
).map(encode_sense)
_acts = st.builds(
    ActMessage,
    tick=st.integers(0, 2**64 - 1),
    duty=st.tuples(*[st.floats(-1, 1)] * 4),
    enabled=st.tuples(*[st.booleans()] * 4),
    watchdog_expired=st.booleans(),
    radio_frames=st.integers(0, 255),
).map(encode_act)
_clocks = st.builds(
    ClockMessage,
    tick=st.integers(0, 2**64 - 1),
    t_ns=st.integers(0, 2**64 - 1),
    dt_ns=st.integers(1, 2**64 - 1),
    lockstep=st.booleans(),
).map(encode_clock)


@HYPOTHESIS
@given(random_or_mutant(_sense_messages, SENSE_DOUBLES), st.sampled_from((None, 12)))
def test_sense_decoder_never_raises_and_names_every_refusal(
    data: bytes, sonar_count: int | None
) -> None:
    outcome = parse_sense(data, sonar_count)
    assert isinstance(outcome, SenseMessage | WireDropReason)
    if isinstance(outcome, SenseMessage):
        check_sense(outcome, len(outcome.sonar_echo_times_s))
    LEDGER.record(
        "wire.sense (hypothesis)", outcome if isinstance(outcome, WireDropReason) else ACCEPTED
    )


@HYPOTHESIS
@given(random_or_mutant(_acts, ACT_DOUBLES))
def test_act_decoder_never_raises_and_names_every_refusal(data: bytes) -> None:
    outcome = parse_act(data)
    assert isinstance(outcome, ActMessage | WireDropReason)
    check_act(outcome)
    LEDGER.record(
        "wire.act (hypothesis)", outcome if isinstance(outcome, WireDropReason) else ACCEPTED
    )


@HYPOTHESIS
@given(random_or_mutant(_clocks))
def test_clock_decoder_never_raises_and_names_every_refusal(data: bytes) -> None:
    outcome = parse_clock(data)
    assert isinstance(outcome, ClockMessage | WireDropReason)
    LEDGER.record(
        "wire.clock (hypothesis)", outcome if isinstance(outcome, WireDropReason) else ACCEPTED
    )


def test_struct_offsets_used_for_mutations_are_the_float_fields() -> None:
    fix = FixSample(1.5, -2.5, 0.25, 7)
    sense = encode_sense(SenseMessage((0, 0, 0, 0), (0.0125,), fix))
    assert [struct.unpack_from("<d", sense, at)[0] for at in SENSE_DOUBLES] == [1.5, -2.5, 0.25]
    assert struct.unpack_from("<f", sense, SENSE_ECHOES_AT)[0] == np.float32(0.0125)
    act = encode_act(ActMessage(1, (0.5, -0.5, 0.25, -0.25), (True,) * 4, False))
    assert [struct.unpack_from("<d", act, at)[0] for at in ACT_DOUBLES] == [0.5, -0.5, 0.25, -0.25]

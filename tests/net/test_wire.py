import math
import struct
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_firmware.net.keys import SwarmKeys, check_name
from robot_firmware.net.wire import (
    MAX_ECHO_TIME_S,
    MAX_SONAR,
    WIRE_VERSION,
    ActMessage,
    ClockMessage,
    FixSample,
    SenseMessage,
    SensePins,
    WireCounters,
    WireDropReason,
    decode_act,
    decode_clock,
    decode_sense,
    encode_act,
    encode_clock,
    encode_sense,
    encode_sense_rows,
    parse_act,
    parse_clock,
    parse_sense,
)


def test_sense_round_trip_keeps_every_field() -> None:
    message = SenseMessage(
        encoder_counts=(1, -2, 3_000_000_000, -(2**40)),
        sonar_echo_times_s=(0.001, None, 0.0125, None),
        fix=FixSample(1.5, -0.25, 3.0, 123_456_789, valid=False),
        tick=42,
        t_ns=987_654_321,
    )
    decoded = decode_sense(encode_sense(message))
    assert decoded is not None
    assert decoded.encoder_counts == message.encoder_counts
    assert decoded.fix == message.fix
    assert decoded.tick == 42 and decoded.t_ns == 987_654_321
    assert decoded.sonar_echo_times_s[1] is None
    assert decoded.sonar_echo_times_s[0] == pytest.approx(0.001)
    no_fix = SenseMessage((0, 0, 0, 0), (), None)
    assert decode_sense(encode_sense(no_fix)) == no_fix


def test_act_and_clock_round_trip() -> None:
    act = ActMessage(7, (0.5, -0.25, 0.0, 1.0), (True, False, True, True), False)
    assert decode_act(encode_act(act)) == act
    clock = ClockMessage(tick=9, t_ns=90_000_000, dt_ns=10_000_000, lockstep=True, epoch=2**32 - 1)
    assert decode_clock(encode_clock(clock)) == clock


def test_sense_and_clock_carry_the_world_epoch() -> None:
    message = SenseMessage((1, 2, 3, 4), (0.5, None), None, tick=3, t_ns=30, epoch=0xDEADBEEF)
    assert decode_sense(encode_sense(message)) == message
    assert decode_sense(encode_sense(message), 2) == message
    clock = ClockMessage(tick=3, t_ns=30, dt_ns=10, lockstep=False, epoch=7)
    assert decode_clock(encode_clock(clock)) == clock


def test_malformed_messages_are_refused() -> None:
    good = encode_act(ActMessage(1, (0.0, 0.0, 0.0, 0.0), (True,) * 4, False))
    assert decode_act(good[:-1]) is None
    assert decode_act(bytes([WIRE_VERSION + 1]) + good[1:]) is None
    bad_duty = struct.pack("<BBBBQ4d", WIRE_VERSION, 0, 0, 0, 1, 2.0, 0.0, 0.0, 0.0)
    assert decode_act(bad_duty) is None
    nan_duty = struct.pack("<BBBBQ4d", WIRE_VERSION, 0, 0, 0, 1, float("nan"), 0.0, 0.0, 0.0)
    assert decode_act(nan_duty) is None
    sense = encode_sense(SenseMessage((0, 0, 0, 0), (0.01,), None))
    assert decode_sense(sense + b"\x00") is None
    assert decode_clock(b"") is None


@settings(max_examples=2000, deadline=None, database=None)
@given(st.binary(max_size=400))
def test_decoders_never_raise_on_random_bytes(data: bytes) -> None:
    for decode in (decode_sense, decode_act, decode_clock):
        decode(data)


def test_keys_follow_the_design_and_names_are_checked() -> None:
    keys = SwarmKeys("lab")
    assert keys.act("robot2") == "swarm/lab/wire/robot2/act"
    assert keys.radio_rx("robot1") == "swarm/lab/radio/rx/robot1"
    assert keys.alive("robot", "robot3") == "swarm/lab/alive/robot/robot3"
    assert keys.admin("robot1", "regs") == "swarm/lab/admin/robot1/regs"
    assert SwarmKeys.last_chunk(keys.telemetry("robot3")) == "robot3"
    with pytest.raises(ValueError, match="lowercase"):
        check_name("robot", "Robot 1")
    with pytest.raises(ValueError):
        SwarmKeys("a/b")


def _act_with_duty(duty_0: float) -> bytes:
    return struct.pack("<BBBBQ4d", WIRE_VERSION, 0, 0, 0, 1, duty_0, 0.0, 0.0, 0.0)


def test_every_refusal_is_named_in_check_order() -> None:
    sense = encode_sense(SenseMessage((0, 0, 0, 0), (0.01, None), None))
    act = encode_act(ActMessage(1, (0.0, 0.0, 0.0, 0.0), (True,) * 4, False))
    clock = encode_clock(ClockMessage(1, 10, 10, False))
    nan_fix = bytearray(sense)
    struct.pack_into("<d", nan_fix, 52, float("nan"))
    far_fix = bytearray(sense)
    struct.pack_into("<d", far_fix, 60, 2e4)
    late_echo = bytearray(sense)
    struct.pack_into("<f", late_echo, 84, 2.0)
    cases = [
        (parse_sense("not bytes", 2), WireDropReason.NOT_BYTES),
        (parse_sense(sense[:10], 2), WireDropReason.TOO_SHORT),
        (parse_sense(sense[:-1], 2), WireDropReason.TOO_SHORT),
        (parse_sense(sense + b"\0", 2), WireDropReason.TOO_LONG),
        (
            parse_sense(bytes([WIRE_VERSION + 1]) + sense[1:], 2),
            WireDropReason.UNSUPPORTED_VERSION,
        ),
        (
            parse_sense(sense[:1] + bytes([MAX_SONAR + 1]) + sense[2:], 2),
            WireDropReason.TOO_MANY_SONARS,
        ),
        (parse_sense(sense[:2] + b"\x08" + sense[3:], 2), WireDropReason.RESERVED_BITS),
        (parse_sense(sense, 3), WireDropReason.WRONG_SONAR_COUNT),
        (parse_sense(bytes(nan_fix), 2), WireDropReason.NON_FINITE),
        (parse_sense(bytes(far_fix), 2), WireDropReason.OUT_OF_RANGE),
        (parse_sense(bytes(late_echo), 2), WireDropReason.OUT_OF_RANGE),
        (parse_act(act[:-1]), WireDropReason.TOO_SHORT),
        (parse_act(act[:1] + b"\x10" + act[2:]), WireDropReason.RESERVED_BITS),
        (parse_act(act[:2] + b"\x02" + act[3:]), WireDropReason.RESERVED_BITS),
        (
            parse_act(struct.pack("<BBBBQ4d", WIRE_VERSION, 0, 0, 0, 1, math.inf, 0, 0, 0)),
            WireDropReason.NON_FINITE,
        ),
        (
            parse_act(struct.pack("<BBBBQ4d", WIRE_VERSION, 0, 0, 0, 1, 1.5, 0, 0, 0)),
            WireDropReason.OUT_OF_RANGE,
        ),
        (parse_clock(clock + b"\0"), WireDropReason.TOO_LONG),
        (parse_clock(clock[:2] + b"\x01\x00" + clock[4:]), WireDropReason.RESERVED_BITS),
        (parse_clock(encode_clock(ClockMessage(1, 10, 0, False))), WireDropReason.OUT_OF_RANGE),
    ]
    for outcome, reason in cases:
        assert outcome == reason
    assert parse_sense(memoryview(sense), 2) == decode_sense(sense)
    assert isinstance(parse_sense(sense, None), SenseMessage)


def test_counters_count_each_message_once_under_its_reason() -> None:
    counters = WireCounters()
    for outcome in (
        WireDropReason.TOO_SHORT,
        WireDropReason.TOO_SHORT,
        ClockMessage(1, 1, 1, True),
    ):
        counters.count(outcome)
    assert counters.accepted == 1 and counters.dropped_total == 2
    assert counters.dropped_as_dict()["too_short"] == 2
    assert set(counters.dropped_as_dict()) == {reason.value for reason in WireDropReason}


@settings(max_examples=60, deadline=None)
@given(
    robots=st.integers(1, 6),
    n_sonar=st.integers(0, 5),
    with_fix=st.booleans(),
    lockstep=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_sense_rows_are_byte_for_byte_the_single_messages(
    robots: int, n_sonar: int, with_fix: bool, lockstep: bool, seed: int
) -> None:
    """The world's batch encoder gives each robot exactly what `encode_sense` gives it."""
    rng = np.random.default_rng(seed)
    echoes = rng.uniform(0.0, MAX_ECHO_TIME_S, (robots, n_sonar))
    echoes[rng.random((robots, n_sonar)) < 0.4] = np.nan
    pins = SensePins(
        encoder_counts=rng.integers(-(2**40), 2**40, (robots, 4)),
        echo_times_s=echoes,
        fix_pose=rng.uniform(-50.0, 50.0, (robots, 3)) if with_fix else None,
        fix_valid=rng.random(robots) < 0.5,
        t_ns=int(rng.integers(0, 2**62)),
    )
    frames = [int(f) for f in rng.integers(0, 400, robots)]
    tick, epoch = int(rng.integers(0, 2**62)), int(rng.integers(1, 2**32))
    rows = encode_sense_rows(pins, tick, lockstep, frames, epoch)
    singles = [encode_sense(m) for m in pins.messages(tick, lockstep, frames, epoch)]
    assert rows == singles
    for row, message in zip(rows, pins.messages(tick, lockstep, frames, epoch), strict=True):
        parsed = parse_sense(row, n_sonar)
        assert isinstance(parsed, SenseMessage)
        # Echo times travel as f32: compare where there is an echo, and to f32 precision.
        sent, got = message.sonar_echo_times_s, parsed.sonar_echo_times_s
        assert [t is None for t in got] == [t is None for t in sent]
        assert [t for t in got if t is not None] == pytest.approx(
            [t for t in sent if t is not None], rel=1e-6
        )
        expected = replace(message, radio_frames=min(message.radio_frames, 255))
        assert replace(parsed, sonar_echo_times_s=sent) == expected

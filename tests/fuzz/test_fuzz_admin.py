"""Fuzzing the admin request body of every verb, through the dispatcher the processes use.

The handlers are the processes' own (`admin_handlers()` of a real robot process, world process
and launcher, built without a network; the launcher's children are stand-ins), called through
`robot_firmware.net.admin.answer` with an `AdminCounters`.  For each verb, 10,000 bodies:
random bytes, random JSON, requests of the verb's shape with a field mutated, and (for
`params`) parameter files mutated as text.  Every input must be answered by the handler
itself (the dispatcher's safety net, `handler_failed`, stays at zero), every refusal is an
`AdminError` with a reason and a message, and a refused request changes nothing: the register
file, the fuzzy parameters and the rule base in use, the link profile, the process table.
"""

from __future__ import annotations

import json
import math
import random
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import BaseModel

from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from robot_firmware.net.admin import AdminCounters, Handler, answer, count_answer
from robot_firmware.net.answers import DeferredAnswer
from robot_firmware.net.messages import AdminError, AdminRefusal
from services.launcher.launcher import Launcher, LaunchPlan
from swarm_config.radio import PROFILES
from tests.fuzz.generate import (
    NASTY_JSON,
    YAML_TRAPS,
    alias_bomb,
    json_bytes,
    mutate_json,
    mutate_text,
    random_bytes,
    random_json,
    random_text,
)
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.processes import PAPER, Robot, make_robot, make_world
from tests.support.stand_in_processes import StandInFactory

INPUTS = 10_000
REASONS = frozenset(AdminRefusal)


def fuzz_verb(
    target: str,
    handlers: dict[str, Handler],
    verb: str,
    bodies: Iterator[bytes],
    state: Callable[[], object],
    defect: Callable[[], str | None] = lambda: None,
    settle: Callable[[], None] | None = None,
) -> AdminCounters:
    """Answer every body; refusals must leave `state()` as it was, and after an accepted one
    `defect()` (what is wrong with the state it left, if anything) must be None.  An answer
    given later (`DeferredAnswer`) must be there once `settle()` ran."""
    counters = AdminCounters()
    defects: Counter[str] = Counter()
    for body in bodies:
        before = state()
        given = answer(handlers, verb, body, counters)
        if isinstance(given, DeferredAnswer):
            assert settle is not None, (verb, body[:200])
            settle()
            assert given.answer is not None, (verb, body[:200])
            count_answer(counters, given.answer)
        reply = given if isinstance(given, BaseModel) else given.answer
        reply.model_dump_json()  # what `serve` sends back
        if isinstance(reply, AdminError):
            assert reply.reason in REASONS and reply.error, reply
            assert reply.reason != AdminRefusal.HANDLER_FAILED, (verb, body[:200], reply.error)
            assert state() == before, (verb, body[:200], reply)
            LEDGER.record(target, reply.reason)
        elif (problem := defect()) is not None:
            defects[problem] += 1
            LEDGER.record(target, f"ACCEPTED BUT {problem}")
        else:
            LEDGER.record(target, ACCEPTED)
    assert counters.handler_failures == 0
    assert not defects, f"accepted requests left {dict(defects)}"
    assert counters.answered == LEDGER.inputs(target)
    return counters


def _bodies(seed: int, make: Callable[[random.Random], Any]) -> Iterator[bytes]:
    """INPUTS bodies: a tenth random bytes, a tenth random JSON, the rest from `make`."""
    rng = random.Random(seed)
    for _ in range(INPUTS):
        roll = rng.random()
        if roll < 0.1:
            yield random_bytes(rng, 64)
        elif roll < 0.2:
            yield json_bytes(random_json(rng))
        else:
            body = make(rng)
            yield body if isinstance(body, bytes) else json_bytes(body)


# -- robot ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def robot() -> Robot:
    return make_robot()


def test_regs_requests(robot: Robot) -> None:
    bus = robot.process.fabric.bus
    addresses = [base + reg.offset for base, p in bus.mapped() for reg in p.registers]

    def request(rng: random.Random) -> Any:
        if rng.random() < 0.02:
            return rng.choice((b"", {"op": "dump"}))
        address = rng.choice(
            (
                rng.choice(addresses),
                rng.choice(addresses) + rng.choice((1, 2, 3, 4, 0x100)),
                rng.randrange(2**32),
                rng.choice(NASTY_JSON),
            )
        )
        body: dict[str, Any] = {"op": rng.choice(("read", "write", "write", "poke", 1, None))}
        if rng.random() < 0.95:
            body["address"] = address
        if rng.random() < 0.8:
            body["value"] = rng.choice((rng.randrange(2**32), rng.choice(NASTY_JSON)))
        return mutate_json(rng, body) if rng.random() < 0.3 else body

    counters = fuzz_verb(
        "admin robot/regs",
        robot.process.admin_handlers(),
        "regs",
        _bodies(1, request),
        robot.registers,
    )
    assert counters.refused[AdminRefusal.BUS_ERROR] > 0
    assert counters.refused[AdminRefusal.INVALID_REQUEST] > 0


def _parameter_file(rng: random.Random) -> dict[str, Any]:
    def centres() -> list[float]:
        count = rng.randint(2, 7)
        return [round(-1.0 + 2.0 * i / (count - 1), 6) for i in range(count)]

    errors, rates = centres(), centres()
    parameters: dict[str, Any] = {"error_centres": errors, "rate_centres": rates}
    if rng.random() < 0.5:
        parameters["rule_outputs"] = [[round(rng.uniform(-1, 1), 3) for _ in rates] for _ in errors]
    return parameters


def _centre_problem(parameters: FuzzyParameters | None) -> str | None:
    """What makes accepted membership centres unusable (NaN or infinity)."""
    if parameters is None:
        return None
    centres = [*parameters.error_centres, *parameters.rate_centres]
    return None if all(math.isfinite(c) for c in centres) else "non-finite centres"


def test_params_requests(robot: Robot) -> None:
    process = robot.process

    def parameter_file(rng: random.Random) -> bytes:
        parameters = _parameter_file(rng)
        roll = rng.random()
        if roll < 0.3:
            return json_bytes(mutate_json(rng, parameters))
        text = yaml.safe_dump(parameters, sort_keys=False)
        if roll < 0.8:
            return mutate_text(rng, text).encode("utf-8", "surrogatepass")
        if roll < 0.9:
            return random_text(rng).encode()
        return text.encode()

    counters = fuzz_verb(
        "admin robot/params",
        process.admin_handlers(),
        "params",
        _bodies(2, parameter_file),
        lambda: (process.fuzzy_parameters, id(process.firmware.rules)),
        lambda: _centre_problem(process.fuzzy_parameters),
    )
    assert counters.refused[AdminRefusal.NOT_YAML] > 0
    assert counters.refused[AdminRefusal.INVALID_REQUEST] > 0
    assert isinstance(process.fuzzy_parameters, FuzzyParameters)


def test_robot_status_requests(robot: Robot) -> None:
    process = robot.process
    fuzz_verb(
        "admin robot/status",
        process.admin_handlers(),
        "status",
        _bodies(3, lambda rng: {"op": rng.choice(NASTY_JSON)}),
        lambda: (robot.registers(), process.fuzzy_parameters),
    )


_REGISTER_FAULTS: tuple[dict[str, Any], ...] = (
    {"fault": "encoder_stuck", "wheel": 1},
    {"fault": "encoder_bit_stuck", "wheel": 2, "bit": 12, "value": 1},
    {"fault": "sonar_no_echo"},
    {"fault": "pwm_stuck", "wheel": 0, "duty": 0.37},
    {"fault": "pwm_saturated", "wheel": 3, "sign": -1},
    {"fault": "fix_cut"},
    {"fault": "watchdog_expire"},
    {"fault": "tick_slow", "extra_ms": 4.0},
    {"fault": "clear_registers"},
)
"""One valid body per register fault (the robot is filled in)."""

_OTHER_FAULTS: tuple[dict[str, Any], ...] = (
    {"fault": "kill", "process": "robot3"},
    {"fault": "stop", "process": "robot2"},
    {"fault": "cont", "process": "robot2"},
    {"fault": "restart", "process": "dashboard"},
    {"fault": "net", "loss": 0.3},
    {"fault": "net", "robot": "robot3", "latency_ms": 40.0, "jitter_ms": 5.0},
    {
        "fault": "net",
        "link": ["robot1", "robot2"],
        "burst": {"good_to_bad": 0.1, "bad_to_good": 0.5},
    },
    {"fault": "partition", "robots": ["robot3"]},
    {"fault": "heal"},
)
"""One valid body per process and network fault (no world or router fault: the fuzzed world
has no launcher to end it)."""


def _fault_request(rng: random.Random, robots: tuple[str, ...]) -> Any:
    if rng.random() < 0.6:
        body = dict(rng.choice(_REGISTER_FAULTS))
        body["robot"] = rng.choice((*robots, "robot9", "", "Robot1", *NASTY_JSON[:4]))
    else:
        body = dict(rng.choice(_OTHER_FAULTS))
    return mutate_json(rng, body) if rng.random() < 0.5 else body


def test_robot_fault_requests(robot: Robot) -> None:
    faults = robot.process.fabric.faults

    def state() -> object:
        return robot.registers(), faults.labels, robot.process.fabric.hw_read_actuation()

    counters = fuzz_verb(
        "admin robot/fault",
        robot.process.admin_handlers(),
        "fault",
        _bodies(8, lambda rng: _fault_request(rng, (robot.process.config.name,))),
        state,
    )
    assert counters.refused[AdminRefusal.INVALID_REQUEST] > 0
    assert counters.refused[AdminRefusal.UNKNOWN_ROBOT] > 0
    faults.clear()


# -- world ---------------------------------------------------------------------------------------


def test_world_net_requests() -> None:
    world = make_world()
    profiles = [p.model_dump(exclude_none=True) for p in PROFILES.values()]

    def request(rng: random.Random) -> Any:
        roll = rng.random()
        if roll < 0.2:
            return {"profile": rng.choice((*PROFILES, "", "LAB", "unknown", *NASTY_JSON[:8]))}
        if roll < 0.25:
            return rng.choice(("[" * 100_000, "{" * 5, "[]", "null")).encode()
        profile = dict(rng.choice(profiles))
        if rng.random() < 0.5:
            profile = {rng.choice(("loss", "latency_ms", "jitter_ms", "range_m")): 0.1}
        return mutate_json(rng, profile)

    fuzz_verb(
        "admin world/net",
        world.admin_handlers(),
        "net",
        _bodies(4, request),
        lambda: world.engine.link,
    )


def test_world_fault_requests() -> None:
    """With no robot up, a register fault is refused as unreachable and a process fault as
    unanswered; network faults are applied to the radio medium."""
    world = make_world()
    names = world.names

    def state() -> object:
        return json.dumps(world.engine.network.export_state(), sort_keys=True)

    counters = fuzz_verb(
        "admin world/fault",
        world.admin_handlers(),
        "fault",
        _bodies(9, lambda rng: _fault_request(rng, names)),
        state,
        settle=world.faults.poll,
    )
    assert counters.refused[AdminRefusal.INVALID_REQUEST] > 0
    assert counters.refused[AdminRefusal.UNKNOWN_ROBOT] > 0
    assert counters.refused[AdminRefusal.UNREACHABLE] > 0


def test_world_status_requests() -> None:
    world = make_world()
    fuzz_verb(
        "admin world/status",
        world.admin_handlers(),
        "status",
        _bodies(5, lambda rng: rng.choice(NASTY_JSON)),
        lambda: (world.engine.link, world.engine.t_ns, world.duty.tobytes()),
    )


# -- launcher ------------------------------------------------------------------------------------


@pytest.fixture
def launcher(tmp_path: Path) -> Iterator[tuple[Launcher, StandInFactory]]:
    factory = StandInFactory()
    plan = LaunchPlan(
        scenario=PAPER, robots=("robot1", "robot2", "robot3"), out_dir=tmp_path, dashboard=False
    )
    launcher = Launcher(plan, factory=factory)  # type: ignore[arg-type]
    for name in launcher.children:
        launcher.start(name)
    yield launcher, factory
    launcher.shutdown(grace_s=0.0)


def _process_request(rng: random.Random) -> Any:
    name = rng.choice(("robot1", "robot2", "robot3", "robot4", "world", "router", "", "Robot1"))
    body: Any = {"process": name if rng.random() < 0.8 else rng.choice(NASTY_JSON)}
    return mutate_json(rng, body) if rng.random() < 0.3 else body


@pytest.mark.parametrize("verb", ["status", "kill", "restart", "stop", "cont"])
def test_launcher_requests(launcher: tuple[Launcher, StandInFactory], verb: str) -> None:
    process_table, factory = launcher

    def state() -> object:
        return json.dumps({n: s.model_dump() for n, s in process_table.status().items()}), len(
            factory.started
        )

    counters = fuzz_verb(
        f"admin launcher/{verb}",
        process_table.admin_handlers(),
        verb,
        _bodies(6, _process_request),
        state,
    )
    if verb != "status":
        assert counters.refused[AdminRefusal.UNKNOWN_PROCESS] > 0
        assert counters.refused[AdminRefusal.NOT_JSON] > 0
    # Only the launcher's own processes are killed or restarted.
    assert set(process_table.children) == {"router", "world", "robot1", "robot2", "robot3"}


def test_unknown_verbs_are_refused_by_name() -> None:
    world = make_world()
    rng = random.Random(7)
    counters = AdminCounters()
    for _ in range(1_000):
        verb = rng.choice(("", "Status", "net/x", "regs", "*", "kill", "\u00e9", "status "))
        reply = answer(world.admin_handlers(), verb, random_bytes(rng, 16), counters)
        if verb in ("regs", "kill", "Status", "", "*", "net/x", "\u00e9", "status "):
            assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.UNKNOWN_VERB
            LEDGER.record("admin unknown verbs", reply.reason)
    assert counters.refused[AdminRefusal.UNKNOWN_VERB] == counters.answered


def test_yaml_traps_in_a_parameter_file_are_refused(robot: Robot) -> None:
    for trap in YAML_TRAPS:
        reply = answer(
            robot.process.admin_handlers(), "params", f"error_centres: {trap}\n".encode()
        )
        assert isinstance(reply, AdminError) and reply.reason != AdminRefusal.HANDLER_FAILED, trap


def test_a_parameter_file_of_expanding_aliases_is_refused_and_the_old_parameters_stay(
    robot: Robot,
) -> None:
    """Under 1,000 bytes of aliases standing for 10**8 values: a robot's `params` reads its
    file with the one loader every file format goes through, which refuses them unwalked."""
    handlers = robot.process.admin_handlers()
    before = answer(handlers, "params", b"")
    bomb = f"note: {alias_bomb(8)}\nerror_centres: [-1, 0, 1]\nrate_centres: [-1, 0, 1]\n"
    bomb = bomb.encode()
    assert len(bomb) < 1_000
    reply = answer(handlers, "params", bomb)
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.NOT_YAML
    assert "aliases expand to more than 1,000,000 values" in reply.error
    assert answer(handlers, "params", b"") == before


def test_a_parameter_file_with_a_key_twice_is_refused_and_the_old_parameters_stay(
    robot: Robot,
) -> None:
    handlers = robot.process.admin_handlers()
    before = answer(handlers, "params", b"")
    # Valid as either of its two `error_centres`: PyYAML alone would take the second.
    repeated = b"error_centres: [-1, 0, 1]\nrate_centres: [-1, 0, 1]\nerror_centres: [-1, 1]\n"
    reply = answer(handlers, "params", repeated)
    assert isinstance(reply, AdminError) and reply.reason == AdminRefusal.NOT_YAML
    assert "twice" in reply.error
    assert answer(handlers, "params", b"") == before

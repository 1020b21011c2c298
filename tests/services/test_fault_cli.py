"""`swarm fault ...`: the arguments of each subcommand become the fault model the world reads;
bad input is refused naming the field and its flag, with status 2 and nothing sent."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from robot_firmware.net.messages import ProcessRequest
from services.cli import main as cli
from services.cli.faults import (
    FAULT_HELP,
    FAULT_MODELS,
    FaultArgumentError,
    command_name,
    fault_from_args,
    fault_json,
)
from swarm_config.credentials import OPERATOR, generate_credential_set, write_credential_set
from swarm_config.faults import (
    FAULT_ADAPTER,
    FAULT_NAMES,
    ClearRegistersFault,
    ContFault,
    EncoderBitStuckFault,
    EncoderStuckFault,
    Fault,
    FixCutFault,
    HealFault,
    KillFault,
    NetFault,
    PartitionFault,
    PwmSaturatedFault,
    PwmStuckFault,
    RestartFault,
    ScheduledFault,
    SonarNoEchoFault,
    StopFault,
    TickSlowFault,
    WatchdogExpireFault,
)
from swarm_config.radio import BurstLoss


def _fault(*argv: str) -> Fault:
    return fault_from_args(cli.build_parser().parse_args(["fault", *argv]))


CASES: list[tuple[list[str], Fault]] = [
    (["kill", "robot2"], KillFault(fault="kill", process="robot2")),
    (["stop", "world"], StopFault(fault="stop", process="world")),
    (["cont", "router"], ContFault(fault="cont", process="router")),
    (["restart", "dashboard"], RestartFault(fault="restart", process="dashboard")),
    (["net", "--loss", "0.25"], NetFault(fault="net", loss=0.25)),
    (
        ["net", "--robot", "robot3", "--latency-ms", "40", "--jitter-ms", "10"],
        NetFault(fault="net", robot="robot3", latency_ms=40.0, jitter_ms=10.0),
    ),
    (
        ["net", "--link", "robot1,robot2", "--burst", "0.05,0.4,0.01"],
        NetFault(
            fault="net",
            link=("robot1", "robot2"),
            burst=BurstLoss(good_to_bad=0.05, bad_to_good=0.4, loss_in_good=0.01),
        ),
    ),
    (
        ["partition", "robot2", "robot3"],
        PartitionFault(fault="partition", robots=("robot2", "robot3")),
    ),
    (["heal"], HealFault(fault="heal")),
    (
        ["encoder-stuck", "robot2", "--wheel", "3"],
        EncoderStuckFault(fault="encoder_stuck", robot="robot2", wheel=3),
    ),
    (
        ["encoder-bit-stuck", "robot1", "--wheel", "0", "--bit", "12", "--value", "1"],
        EncoderBitStuckFault(fault="encoder_bit_stuck", robot="robot1", wheel=0, bit=12, value=1),
    ),
    (["sonar-no-echo", "robot3"], SonarNoEchoFault(fault="sonar_no_echo", robot="robot3")),
    (
        ["pwm-stuck", "robot2", "--wheel", "1", "--duty", "-0.4"],
        PwmStuckFault(fault="pwm_stuck", robot="robot2", wheel=1, duty=-0.4),
    ),
    (
        ["pwm-saturated", "robot2", "--wheel", "2"],
        PwmSaturatedFault(fault="pwm_saturated", robot="robot2", wheel=2, sign=1),
    ),
    (
        ["pwm-saturated", "robot2", "--wheel", "2", "--sign", "-1"],
        PwmSaturatedFault(fault="pwm_saturated", robot="robot2", wheel=2, sign=-1),
    ),
    (["fix-cut", "robot1"], FixCutFault(fault="fix_cut", robot="robot1")),
    (
        ["watchdog-expire", "robot3"],
        WatchdogExpireFault(fault="watchdog_expire", robot="robot3"),
    ),
    (
        ["tick-slow", "robot2", "--extra-ms", "7.5"],
        TickSlowFault(fault="tick_slow", robot="robot2", extra_ms=7.5),
    ),
    (
        ["clear-registers", "robot2"],
        ClearRegistersFault(fault="clear_registers", robot="robot2"),
    ),
]


@pytest.mark.parametrize(("argv", "expected"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_each_subcommand_builds_its_fault(argv: list[str], expected: Fault) -> None:
    built = _fault(*argv)
    assert built == expected
    assert type(built) is type(expected)


def test_every_fault_of_the_schema_has_a_subcommand_a_case_and_help() -> None:
    assert set(FAULT_MODELS) == set(FAULT_NAMES) == set(FAULT_HELP)
    assert {expected.fault for _, expected in CASES} == set(FAULT_NAMES)
    parser = cli.build_parser()
    for name in FAULT_NAMES:
        for spelling in {name, command_name(name)}:
            args = parser.parse_args(["fault", spelling, *_minimal_arguments(name)])
            assert args.fault_name == name
        text = FAULT_HELP[name]
        assert text.summary and text.does and text.swarm


def _minimal_arguments(name: str) -> list[str]:
    argv = next(a for a, expected in CASES if expected.fault == name)
    return argv[1:]


def test_the_json_form_takes_any_fault_as_a_schedule_entry_holds_it() -> None:
    for _, expected in CASES:
        text = fault_json(expected).decode()
        assert _fault("--json", text) == expected
        entry = ScheduledFault.model_validate({"at_s": 3.0, "fault": json.loads(text)})
        assert entry.fault == expected


def test_admin_options_count_before_and_after_the_subcommand() -> None:
    parser = cli.build_parser()
    before = parser.parse_args(
        ["fault", "--connect", "tcp/10.0.0.1:7447", "--timeout", "9", "kill", "robot2"]
    )
    assert (before.connect, before.timeout, before.swarm) == ("tcp/10.0.0.1:7447", 9.0, None)
    after = parser.parse_args(["fault", "kill", "robot2", "--swarm", "bay", "--timeout", "4"])
    assert (after.connect, after.timeout, after.swarm) == (None, 4.0, "bay")
    plain = parser.parse_args(["fault", "heal"])
    assert (plain.connect, plain.timeout, plain.dry_run) == (None, 3.0, False)


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["pwm-stuck", "robot2", "--wheel", "1", "--duty", "1.5"], "duty (--duty)"),
        (["encoder-stuck", "robot2", "--wheel", "4"], "wheel (--wheel)"),
        (
            ["encoder-bit-stuck", "robot1", "--wheel", "0", "--bit", "32", "--value", "1"],
            "bit (--bit)",
        ),
        (
            ["encoder-bit-stuck", "robot1", "--wheel", "0", "--bit", "3", "--value", "2"],
            "value (--value)",
        ),
        (["tick-slow", "robot1", "--extra-ms", "0"], "extra_ms (--extra-ms)"),
        (["net", "--loss", "1.5"], "loss (--loss)"),
        (["net", "--burst", "0.1,0"], "burst.bad_to_good (--burst)"),
        (["net"], "nothing to set"),
        (["net", "--robot", "robot1", "--link", "robot1,robot2", "--loss", "0.1"], "not both"),
        (["net", "--link", "robot1,robot1", "--loss", "0.1"], "two different robots"),
        (["net", "--loss", "0.1", "--burst", "0.1,0.5"], "either 'loss'"),
        (["kill", "Robot2"], "process (PROCESS)"),
        (["fix-cut", "robot 2"], "robot"),
        (["--json", '{"fault": "pwm_stuck", "robot": "robot2", "wheel": 0}'], "duty: Field"),
        (["--json", '{"fault": "kill", "process": "robot2", "extra": 1}'], "extra"),
        (["--json", '{"fault": "melt", "robot": "robot2"}'], "'melt' is not a fault"),
        (["--json", "{not json"], "--json is not JSON"),
        # Before, true was taken for 1: a 1 ms tick_slow, bit 1 of an encoder.
        (["--json", '{"fault": "tick_slow", "robot": "robot2", "extra_ms": true}'], "extra_ms"),
        (
            ["--json", '{"fault": "net", "latency_ms": false}'],
            "--json: latency_ms: a number, not false",
        ),
        (["--json", "[" * 100_000 + "]" * 100_000], "--json is not JSON"),
        (["--json", '"kill"'], "one JSON object"),
        (["--json", '{"fault": "heal"}', "heal"], "not both"),
        ([], "name a fault"),
    ],
)
def test_bad_input_is_refused_naming_the_field(argv: list[str], named: str) -> None:
    with pytest.raises(FaultArgumentError) as refused:
        _fault(*argv)
    assert named in str(refused.value)


@pytest.mark.parametrize(
    "argv",
    [
        ["pwm-stuck", "robot2", "--wheel", "x", "--duty", "0.1"],
        ["pwm-stuck", "robot2", "--duty", "0.1"],
        ["net", "--link", "robot1", "--loss", "0.1"],
        ["net", "--burst", "a,b"],
        ["partition"],
    ],
)
def test_arguments_argparse_cannot_read_exit_with_status_2(argv: list[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        cli.build_parser().parse_args(["fault", *argv])
    assert exited.value.code == cli.EXIT_USAGE


class _Admin:
    """Stands in for `robot_firmware.net.admin.ask`: records each request, answers from a
    table of (target, verb) -> reply payload (None: nobody answers)."""

    def __init__(self, answers: dict[tuple[str, str], bytes | None]) -> None:
        self.answers = answers
        self.asked: list[tuple[str, str, bytes]] = []

    def __call__(
        self,
        swarm: str,
        endpoint: str,
        target: str,
        verb: str,
        body: object = None,
        timeout_s: float = 3.0,
        credentials: object = None,
    ) -> bytes | None:
        payload = body.model_dump_json().encode() if hasattr(body, "model_dump_json") else body
        assert payload is None or isinstance(payload, bytes)
        self.asked.append((target, verb, payload or b""))
        return self.answers.get((target, verb))


@pytest.fixture
def operator(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    files = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1", "robot2"))
    )
    monkeypatch.setenv("SWARM_CREDENTIALS_FILE", str(files[OPERATOR]))
    return files[OPERATOR]


def _install(monkeypatch: pytest.MonkeyPatch, admin: _Admin) -> None:
    monkeypatch.setattr("robot_firmware.net.admin.ask", admin)


WORLD_REPLY = b'{"ok": true, "event": {"t_s": 1.0, "kind": "fault_injected"}}'
WORLD_STATUS = b'{"ok": true, "t_s": 1.0}'


def test_the_fault_goes_to_the_worlds_fault_verb_as_its_json(
    operator: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = _Admin({("world", "status"): WORLD_STATUS, ("world", "fault"): WORLD_REPLY})
    _install(monkeypatch, admin)
    code = cli.main(["fault", "pwm-stuck", "robot2", "--wheel", "0", "--duty", "0.5"])
    assert code == 0
    status, (target, verb, body) = admin.asked
    assert status[:2] == ("world", "status") and (target, verb) == ("world", "fault")
    assert FAULT_ADAPTER.validate_json(body) == PwmStuckFault(
        fault="pwm_stuck", robot="robot2", wheel=0, duty=0.5
    )
    assert json.loads(capsys.readouterr().out)["event"]["kind"] == "fault_injected"


def test_a_refusal_of_the_world_exits_with_status_1(
    operator: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    refusal = b'{"ok": false, "error": "no robot robot9", "reason": "unknown_robot"}'
    _install(monkeypatch, _Admin({("world", "status"): WORLD_STATUS, ("world", "fault"): refusal}))
    assert cli.main(["fault", "fix-cut", "robot9"]) == 1


@pytest.mark.parametrize(
    "argv",
    [
        ["pwm-stuck", "robot2", "--wheel", "0", "--duty", "2"],
        ["--json", '{"fault": "net"}'],
        ["net", "--loss", "-0.1"],
    ],
)
def test_bad_input_exits_with_status_2_and_sends_nothing(
    operator: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
) -> None:
    admin = _Admin({("world", "status"): WORLD_STATUS, ("world", "fault"): WORLD_REPLY})
    _install(monkeypatch, admin)
    assert cli.main(["fault", *argv]) == cli.EXIT_USAGE
    assert admin.asked == []
    error = capsys.readouterr().err
    assert error.startswith("swarm fault: invalid fault:") and "Traceback" not in error


def test_a_process_fault_goes_to_the_launcher_when_the_world_does_not_answer(
    operator: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = _Admin({("launcher", "cont"): b'{"ok": true, "continued": true}'})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "cont", "world"]) == 0
    assert [(target, verb) for target, verb, _ in admin.asked] == [
        ("world", "status"),
        ("launcher", "cont"),
    ]
    assert ProcessRequest.model_validate_json(admin.asked[1][2]) == ProcessRequest(process="world")
    captured = capsys.readouterr()
    assert "the world does not answer" in captured.err
    assert json.loads(captured.out) == {"ok": True, "continued": True}


@pytest.mark.parametrize(
    ("process", "said"), [("world", "took `restart` on itself"), ("router", "went down with it")]
)
def test_a_restart_of_the_world_or_router_unanswered_shows_the_launchers_status(
    operator: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    process: str,
    said: str,
) -> None:
    status = b'{"ok": true, "processes": {}}'
    admin = _Admin({("world", "status"): WORLD_STATUS, ("launcher", "status"): status})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "restart", process]) == 0
    # Sent once, to the world: never again to the launcher, which would restart it twice.
    assert [(target, verb) for target, verb, _ in admin.asked] == [
        ("world", "status"),
        ("world", "fault"),
        ("launcher", "status"),
    ]
    assert said in capsys.readouterr().err


def test_a_robot_fault_the_world_does_not_answer_is_not_sent_elsewhere(
    operator: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = _Admin({("world", "status"): WORLD_STATUS})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "kill", "robot2"]) == cli.EXIT_USAGE
    # The launcher is asked only for its status, to say why the world does not answer.
    assert [(target, verb) for target, verb, _ in admin.asked] == [
        ("world", "status"),
        ("world", "fault"),
        ("launcher", "status"),
    ]
    assert "no answer from world" in capsys.readouterr().err


def test_another_fault_nobody_answers_is_a_clear_error(
    operator: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = _Admin({})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "heal", "--timeout", "0.1"]) == cli.EXIT_USAGE
    assert [(target, verb) for target, verb, _ in admin.asked] == [
        ("world", "status"),
        ("launcher", "status"),
    ]
    assert "no answer from world" in capsys.readouterr().err


def test_dry_run_prints_the_json_and_sends_nothing(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = _Admin({})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "partition", "robot3", "--dry-run"]) == 0
    assert admin.asked == []
    printed = capsys.readouterr().out
    assert FAULT_ADAPTER.validate_json(printed) == PartitionFault(
        fault="partition", robots=("robot3",)
    )


@pytest.mark.parametrize(
    ("world", "said"),
    [
        ({"running": False, "killed": True, "stopped": False, "exit_code": -9},
         "it was killed and stays down: `swarm restart world` starts it again"),
        ({"running": True, "killed": False, "stopped": True, "exit_code": None},
         "it is stopped: `swarm fault cont world` continues it"),
        ({"running": False, "killed": False, "stopped": False, "exit_code": 3},
         "it exited by itself (status 3): see /runs/logs/world.log"),
    ],
)  # fmt: skip
def test_a_world_that_does_not_answer_is_explained_from_the_launchers_status(
    operator: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    world: dict[str, object],
    said: str,
) -> None:
    # Before: "(is it running? start one with `swarm up`)" while the swarm ran.
    process = {"pid": 41, "restarts": 0, "log": "/runs/logs/world.log", **world}
    status = json.dumps({"ok": True, "processes": {"world": process}}).encode()
    admin = _Admin({("launcher", "status"): status})
    _install(monkeypatch, admin)
    assert cli.main(["fault", "heal", "--timeout", "0.1"]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert said in err and "start one with" not in err, err


@pytest.mark.parametrize("name", ["heal", "net"])
def test_heal_and_net_help_say_the_running_profile_stays(
    capsys: pytest.CaptureFixture[str], name: str
) -> None:
    # Before, it said "back to the scenario's profile", but heal clears only the faults and
    # keeps the profile of the last `swarm net set`.
    with pytest.raises(SystemExit) as exited:
        cli.main(["fault", name, "--help"])
    assert exited.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "scenario's profile" not in text
    assert "the radio profile in effect (the scenario's, or the last `swarm net set`" in text
    if name == "heal":
        assert "every partition and every `swarm fault net` override" in text

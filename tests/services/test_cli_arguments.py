"""The live commands refuse, before they connect, what cannot be a key or a bus access."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from services.cli.main import PARAMS_FILE_BYTES_MAX, main
from swarm_config.credentials import (
    OPERATOR,
    WORLD,
    generate_credential_set,
    write_credential_set,
)
from tests.support.cli_refusals import forbid_zenoh_sessions, refusal_lines

ROOT = Path(__file__).resolve().parents[2]
NOBODY = "tcp/127.0.0.1:9"
"""An endpoint where no router listens (no test here gets as far as connecting)."""


@pytest.fixture(autouse=True)
def _no_session_may_open(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each refusal here must come before the command opens a Zenoh session."""
    forbid_zenoh_sessions(monkeypatch)


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    return refusal_lines(argv, capsys)[-1]


@pytest.mark.parametrize(
    ("address", "value", "named"),
    [
        ("-1", None, "argument ADDR: '-1' does not fit the 32-bit bus"),
        ("0x100000000", None, "argument ADDR: '0x100000000' does not fit the 32-bit bus"),
        ("0x0", "0x1FFFFFFFF", "argument VALUE: '0x1FFFFFFFF' does not fit the 32-bit bus"),
        ("0x0", "-5", "argument VALUE: '-5' does not fit the 32-bit bus"),
        ("nope", None, "argument ADDR: 'nope' is not an integer"),
    ],
)
def test_a_bus_access_outside_32_bits_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], address: str, value: str | None, named: str
) -> None:
    argv = ["regs", "robot1", address, *([value] if value else []), "--connect", NOBODY]
    assert named in _refused(argv, capsys)


@pytest.mark.parametrize("target", ["", "**", "robot1/x", "Robot1"])
@pytest.mark.parametrize("command", ["regs", "params"])
def test_a_target_that_is_not_one_key_chunk_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], command: str, target: str
) -> None:
    line = _refused([command, target, "--connect", NOBODY], capsys)
    assert line.startswith(f"swarm {command}: process name {target!r} must be 1-32 characters")


def test_a_swarm_name_that_is_not_one_key_chunk_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    line = _refused(["status", "--swarm", "*", "--connect", NOBODY], capsys)
    assert line.startswith("swarm status: --swarm: swarm name '*' must be")
    monkeypatch.setenv("SWARM_NAME", "a/b")
    line = _refused(["status", "--connect", NOBODY], capsys)
    assert line.startswith("swarm status: $SWARM_NAME: swarm name 'a/b' must be")
    line = _refused(["credentials", "--swarm", "**", str(tmp_path / "creds")], capsys)
    assert line.startswith("swarm credentials: --swarm: swarm name '**' must be")
    assert not (tmp_path / "creds").exists()
    # A long one is named by its start and length (it was echoed whole: 5,000 characters).
    line = _refused(["status", "--swarm", "s" * 5000, "--connect", NOBODY], capsys)
    assert f"swarm name {'s' * 32!r}... (5000 characters) must be" in line and len(line) < 250


def test_a_parameter_file_too_large_for_the_router_is_refused_before_sending(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    large = tmp_path / "fuzzy.yaml"
    large.write_bytes(b"#" * (PARAMS_FILE_BYTES_MAX + 1))
    line = _refused(["params", "robot1", str(large), "--connect", NOBODY], capsys)
    assert line == (
        f"swarm params: {large}: fuzzy parameter file is larger than "
        f"{PARAMS_FILE_BYTES_MAX:,} bytes"
    )
    line = _refused(["params", "robot1", str(tmp_path), "--connect", NOBODY], capsys)
    assert line.endswith("cannot read fuzzy parameter file (Is a directory)")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["status", "--connect", "nonsense"], "argument --connect: 'nonsense' is not <protocol>"),
        (["status", "--connect", ","], "argument --connect: ',' names no endpoint"),
        (["regs", "robot1", "--connect", "foo/bar:1"], "no protocol 'foo'"),
        (["router", "--listen", "tcp/127.0.0.1:99999"], "a port in 1-65535"),
        (["credentials", "--listen", "tcp:7447", "DIR"], "argument --listen: 'tcp:7447' is not"),
        (["up", "--connect", "tls/host"], "argument --connect: 'tls/host': the address is not"),
    ],
)
def test_an_endpoint_that_cannot_be_one_is_refused_before_anything_connects(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, argv: list[str], named: str
) -> None:
    folder = tmp_path / "credentials"
    argv = [str(folder) if part == "DIR" else part for part in argv]
    assert named in _refused(argv, capsys)
    assert not folder.exists()


def test_a_zenoh_connect_that_cannot_be_one_is_refused_naming_the_variable(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ZENOH_CONNECT", "garbage")
    line = _refused(["status"], capsys)
    assert line.startswith("swarm status: $ZENOH_CONNECT: 'garbage' is not <protocol>/<address>")


def test_a_router_config_that_cannot_be_read_stops_the_router_in_one_line(tmp_path: Path) -> None:
    not_zenoh = tmp_path / "router.json5"
    not_zenoh.write_text("{ name: 1 }\n")
    for config in (tmp_path / "missing.json5", tmp_path, not_zenoh):
        result = subprocess.run(
            [sys.executable, "-m", "services.cli.main", "router", "--config", str(config)],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=60,
        )
        assert result.returncode == 2, result.stderr
        assert "Traceback" not in result.stderr
        assert f"cannot use the router config {config}" in result.stderr


@pytest.mark.parametrize("command", ["up", "world"])
def test_a_run_shorter_than_one_control_period_is_refused_before_anything_starts(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before, the world ended at its first tick boundary with nothing run.
    out = tmp_path / "run"
    argv = [command, "--duration", "0.004", "--out", str(out)]
    if command == "world":
        credentials = generate_credential_set("lab", ("robot1", "robot2", "robot3"))
        files = write_credential_set(tmp_path / "credentials", credentials)
        argv += ["--credentials", str(files[WORLD])]
    assert _refused(argv, capsys) == (
        f"swarm {command}: duration_s (--duration): 0.004 s is shorter than one control period "
        "of scenario 'paper' (0.01 s): nothing would run"
    )
    assert not out.exists()


PAPER = str(ROOT / "configs" / "scenarios" / "paper.yaml")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["up", "--out", "", "--no-dashboard"], "--out"),
        (["up", "--credentials", ""], "--credentials"),
        (["sim", "--scenario", PAPER, "--out", ""], "--out"),
        (["sim", "--scenario", "", "--out", "run"], "--scenario"),
        (["tune", "--scenario", PAPER, "--out", ""], "--out"),
        (["credentials", ""], "DIR"),
        (["dashboard", "--out", ""], "--out"),
        (["replay", ""], "FILE.rrd"),
        (["status", "--credentials", ""], "--credentials"),
        (["params", "robot1", ""], "FILE"),
        (["world", "--config", ""], "--config"),
        (["scenario", "generate", "--robots", "3", "--out", ""], "--out"),
    ],
)
def test_an_empty_path_is_refused_and_nothing_is_written_here(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    argv: list[str],
    named: str,
) -> None:
    # Before, '' was the current folder: `swarm up --out ''` wrote a whole run into it,
    # credentials included, and `swarm credentials ''` its secrets.
    monkeypatch.chdir(tmp_path)
    refused = _refused(argv, capsys)
    assert f"{named} is an empty path (write . for the current folder)" in refused, refused
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "--scenario", PAPER, "--out", "NAME"],
        ["tune", "--scenario", PAPER, "--out", "NAME", "--budget", "1"],
        ["credentials", "NAME"],
        ["sim", "--scenario", "NAME", "--out", "run"],
    ],
)
def test_a_name_too_long_for_the_file_system_is_one_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, argv: list[str]
) -> None:
    # Before, pathlib's exists() and is_dir() raised ENAMETOOLONG: a traceback.
    too_long = str(tmp_path / ("a" * 300))
    refused = _refused([too_long if word == "NAME" else word for word in argv], capsys)
    assert "File name too long" in refused and too_long in refused, refused


@pytest.mark.parametrize(("command", "process"), [("kill", ""), ("restart", "a/b"), ("kill", "*")])
def test_a_process_that_cannot_be_named_is_refused_before_connecting(
    capsys: pytest.CaptureFixture[str], command: str, process: str
) -> None:
    # Before, `swarm kill ''` went to the launcher, which answered with its list, status 1.
    line = _refused([command, process, "--connect", NOBODY], capsys)
    assert f"argument process: process name {process!r} must be" in line, line


@pytest.mark.parametrize(
    "argv",
    [
        ["status"],
        ["status", "robot2"],
        ["kill", "robot3"],
        ["restart", "robot3"],
        ["regs", "robot1", "0xFF200000"],
        ["params", "robot1"],
        ["net", "get"],
        ["fault", "heal"],
        ["fault", "--timeout", "TIMEOUT", "kill", "robot2"],
    ],
)
@pytest.mark.parametrize("timeout", ["1e20", "1e300", "86400.5"])
def test_a_timeout_over_one_day_is_refused_naming_the_flag(
    capsys: pytest.CaptureFixture[str], argv: list[str], timeout: str
) -> None:
    # Before, 1e20 s and more reached Zenoh, whose `ValueError: negative timeout` was a
    # traceback once a router let the command in.
    if "TIMEOUT" in argv:
        argv = [timeout if word == "TIMEOUT" else word for word in argv]
    else:
        argv = [*argv, "--timeout", timeout]
    line = _refused([*argv, "--connect", NOBODY], capsys)
    assert line.endswith(
        f"argument --timeout: {timeout!r} is more than one day: give at most 86,400 seconds"
    ), line


def test_a_timeout_of_one_day_is_taken_and_an_over_long_one_is_one_line() -> None:
    from services.cli.main import build_parser

    assert build_parser().parse_args(["status", "--timeout", "86400"]).timeout == 86400.0
    done = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "net", "get", "--timeout", "1e20"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        "swarm net: error: argument --timeout: '1e20' is more than one day: give at most "
        "86,400 seconds"
    )


@pytest.fixture
def operator_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    files = write_credential_set(
        tmp_path / "credentials", generate_credential_set("lab", ("robot1", "robot2"))
    )
    monkeypatch.setenv("SWARM_CREDENTIALS_FILE", str(files[OPERATOR]))
    return files[OPERATOR]


class _Asked:
    """Stands in for `robot_firmware.net.admin.ask`: records what is sent, answers ok."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, str, bytes | None]] = []

    def __call__(
        self,
        _swarm: str,
        _endpoint: str,
        target: str,
        verb: str,
        body: object = None,
        *_rest: object,
    ) -> bytes:
        assert body is None or isinstance(body, bytes)
        self.sent.append((target, verb, body))
        return b'{"ok": true}'


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["set", "--profile", "ideal", "--loss", "0.9"], "--loss"),
        (["set", "--profile", "lossy", "--latency-ms", "5", "--jitter-ms", "1"], "--latency-ms"),
        (["set", "--jitter-ms", "1", "--profile", "lab"], "--jitter-ms"),
    ],
)
def test_net_set_refuses_a_profile_with_field_flags_and_sends_nothing(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    operator_file: Path,
    argv: list[str],
    named: str,
) -> None:
    # Before, the profile was sent and the field flags silently dropped, status 0.
    asked = _Asked()
    monkeypatch.setattr("robot_firmware.net.admin.ask", asked)
    line = _refused(["net", *argv, "--connect", NOBODY], capsys)
    assert line.startswith("swarm net: give either --profile or ") and "not both" in line, line
    assert named in line and "then `net set " in line
    assert asked.sent == []
    # Each alone is sent as it was.
    assert main(["net", "set", "--profile", "ideal", "--connect", NOBODY]) == 0
    assert main(["net", "set", "--loss", "0.9", "--connect", NOBODY]) == 0
    assert [json.loads(body or b"") for _, _, body in asked.sent] == [
        {"profile": "ideal"},
        {"loss": 0.9},
    ]


def test_net_get_refuses_the_flags_of_net_set(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, operator_file: Path
) -> None:
    asked = _Asked()
    monkeypatch.setattr("robot_firmware.net.admin.ask", asked)
    line = _refused(["net", "get", "--loss", "0.9", "--connect", NOBODY], capsys)
    assert line == "swarm net: net get takes no --loss: `swarm net set` changes the profile"
    assert asked.sent == []


def test_net_set_help_says_profile_or_fields_not_both(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["net", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "not both" in text and "`net set --profile NAME` then `net set --loss X`" in text


@pytest.mark.parametrize(
    "content", [b"", b"   \n\t\n", b"\n\n", b"# tuned later\n  # nothing yet\n\n", b"\xef\xbb\xbf"]
)
def test_an_empty_parameter_file_is_refused_naming_it_before_connecting(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, content: bytes
) -> None:
    # Before, an empty body went out: the robot's "show the parameters" request, status 0,
    # and nothing said the file was not applied.
    empty = tmp_path / "fuzzy.yaml"
    empty.write_bytes(content)
    line = _refused(["params", "robot1", str(empty), "--connect", NOBODY], capsys)
    assert line.startswith(f"swarm params: {empty}: fuzzy parameter file is empty"), line


@pytest.mark.parametrize(
    "word", [" 12", "12 ", "1_000", "0b101", "0o17", "\u0661\u0662", "+5", "010", "0x", "0x_1F"]
)
@pytest.mark.parametrize("where", ["ADDR", "VALUE"])
def test_a_bus_word_in_another_form_than_decimal_or_0x_hex_is_refused(
    capsys: pytest.CaptureFixture[str], word: str, where: str
) -> None:
    # Before, Python's int(x, 0) took spaces, _, 0b, 0o, a sign and non-ASCII digits.
    given = [word] if where == "ADDR" else ["0xFF200000", word]
    line = _refused(["regs", "robot1", *given, "--connect", NOBODY], capsys)
    assert (
        f"argument {where}: {word!r} is not an integer of the accepted forms: decimal digits "
        "without a leading 0 (e.g. 4096) or 0x and hex digits (e.g. 0xFF200000)"
    ) in line, line


def test_decimal_and_0x_hex_bus_words_are_taken(capsys: pytest.CaptureFixture[str]) -> None:
    from services.cli.main import build_parser

    parse = build_parser().parse_args
    args = parse(["regs", "robot1", "0XFF200810", "4294967295"])
    assert (args.address, args.value) == (0xFF200810, 0xFFFF_FFFF)
    assert parse(["regs", "robot1", "0", "0x0"]).value == 0
    huge = "9" * 5000  # over Python's 4,300 digits of int(): still one line
    line = _refused(["regs", "robot1", huge, "--connect", NOBODY], capsys)
    assert "(5000 characters) does not fit the 32-bit bus" in line and len(line) < 200


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["regs", "router"], "swarm regs: the router answers no admin requests; `swarm status`"),
        (["status", "router"], "swarm status: the router answers no admin requests"),
        (["params", "router"], "swarm params: the router answers no admin requests"),
        (["status", "dashboard"], "swarm status: the dashboard answers no admin requests"),
        (["status", "operator"], "swarm status: operator is the identity of this command line"),
        (["regs", "world", "0x0"], "swarm regs: world is not a robot: only a robot answers"),
        (["params", "launcher"], "swarm params: launcher is not a robot: only a robot answers"),
    ],
)
def test_a_process_that_cannot_answer_the_verb_is_refused_before_connecting(
    capsys: pytest.CaptureFixture[str], operator_file: Path, argv: list[str], expected: str
) -> None:
    # Before, `swarm regs router` waited for --timeout, then blamed a router that "did not
    # answer in time" (the router has no admin verbs at all).
    line = _refused([*argv, "--connect", NOBODY], capsys)
    assert line.startswith(expected), line

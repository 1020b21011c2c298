"""`swarm fault ...`: one subcommand per fault of swarm_config/faults.py, turned into its model.

`add_fault_parser(subparsers, options, handler)` registers `swarm fault` with one subcommand per
fault (`kill`, `stop`, `cont`, `restart`, `net`, `partition`, `heal`, `encoder-stuck`, ...;
the schema's own spelling with `_` works too) and the `--json '{...}'` form for any fault as its
JSON.  `fault_from_args(args)` builds the `Fault` the arguments describe, or raises
`FaultArgumentError` naming the field (and its flag) that is wrong; nothing is sent before it
succeeds.  The command itself (services/cli/main.py) sends the fault to the world's admin verb
`fault`, the one entry point of every fault (DESIGN.md §7).

Each fault's `--help` says what it does and what the swarm does about it; docs/robustness.md
has the figures measured.
"""

from __future__ import annotations

import argparse
import json
import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from swarm_config.faults import (
    FAULT_ADAPTER,
    FAULT_MODELS,
    FAULT_NAMES,
    REGISTER_FAULTS,
    Fault,
    fault_boolean_problems,
    fault_name,
)


class FaultArgumentError(ValueError):
    """The arguments do not describe a valid fault; the message names the field and flag."""


@dataclass(frozen=True)
class FaultHelp:
    summary: str
    """One line for the list of faults."""
    does: str
    """What the fault does."""
    swarm: str
    """What the swarm does about it."""


PROCESS_HELP = "a robot's name (e.g. robot2), world, router or dashboard"

FAULT_HELP: dict[str, FaultHelp] = {
    "kill": FaultHelp(
        "SIGKILL a process (a power cut)",
        "SIGKILL the process, a power cut: no clean-up runs, and it stays down until "
        "`swarm fault restart`.",
        "A robot: its liveliness token goes, the world brakes its body, which stays as an "
        "obstacle, and the others avoid it. The leader: the live follower with the lowest index "
        "takes over its trajectory with a higher term within 0.5 s plus one broadcast period, "
        "and the others re-reference their slots to it. The world: every robot safe-stops "
        "(motors off through the driver and the watchdog IP within 200 ms). The router: the "
        "launcher starts it again at once and every client reconnects. The dashboard: nothing "
        "changes in the swarm; its recording stays readable.",
    ),
    "stop": FaultHelp(
        "SIGSTOP a process (a frozen board)",
        "SIGSTOP the process: a frozen board that keeps its state until `swarm fault cont`.",
        "Its liveliness lease (1 s) runs out: a frozen robot is counted out by the world (its "
        "body braked) and by its peers, exactly as a dead one, and a frozen leader is replaced. "
        "A frozen world sends no sense message, so every robot safe-stops within 200 ms. The "
        "launcher does not restart a stopped process; `swarm status` shows it as stopped.",
    ),
    "cont": FaultHelp(
        "SIGCONT a stopped process",
        "SIGCONT a stopped process: it runs on from where it froze, without a restart.",
        "A robot's first tick after the gap starts afresh: no burst of missed ticks, it "
        "re-localises from the next fix and drops peer states older than the decoder's age "
        "window, then rejoins its slot (as a follower if another robot took the lead).",
    ),
    "restart": FaultHelp(
        "start a process again",
        "Start the process again, SIGKILLing it first if it still runs.",
        "A robot boots as a follower, acts on nothing before its first fix and rejoins the "
        "formation (the slot the new leader vacated, if it led). The world resumes from its "
        "newest valid checkpoint (at most 0.5 simulated seconds old) with a new epoch; the "
        "robots re-synchronise their schedules to it.",
    ),
    "net": FaultHelp(
        "loss, delay, jitter or bursts on all links, one robot's or one link",
        "Change the radio medium on every link (no --robot, no --link), on every link to or "
        "from one robot (--robot) or on one link in both directions (--link A,B): loss, "
        "latency, jitter or Gilbert-Elliott bursts. Fields not given keep the radio profile in "
        "effect (the scenario's, or the last `swarm net set`); `swarm fault heal` undoes it.",
        "Frames arrive late or not at all. Receivers drop frames older than the decoder's age "
        "window and hold a silent peer as a stopped body; a leader unheard for 0.5 s is taken "
        "for dead and a follower takes over; when it is heard again the higher term wins.",
    ),
    "partition": FaultHelp(
        "cut robots off from the rest",
        "Cut ROBOTS (each named once, and not every robot of the swarm) off from the rest: no "
        "frame crosses between the two sides until `swarm fault heal`.",
        "Each side goes on with what it hears. A side without the leader elects its own (the "
        "lowest-index live robot, one term higher); after the heal the higher term wins and the "
        "other leader steps down, so two leaders never both act once they hear each other.",
    ),
    "heal": FaultHelp(
        "undo every network fault",
        "Undo every network fault: every partition and every `swarm fault net` override of "
        "the links is cleared, so every link is back to the radio profile in effect (the "
        "scenario's, or the last `swarm net set`, which heal keeps).",
        "Frames flow again; robots that elected a leader of their own step down to the highest "
        "term and rejoin their slots.",
    ),
    "encoder_stuck": FaultHelp(
        "freeze one wheel's encoder count",
        "The QEP count of one wheel stops changing, as if its encoder lines were cut.",
        "The firmware sees it only through the QEP register: its odometry believes that wheel "
        "stands still, so its estimate drifts between positioning fixes, and each fix pulls it "
        "back.",
    ),
    "encoder_bit_stuck": FaultHelp(
        "force one bit of one wheel's encoder count",
        "One bit of one wheel's QEP count register reads VALUE whatever the count.",
        "The firmware sees count jumps of 2^BIT: odometry spikes that the positioning fixes "
        "pull back; a high bit makes the estimate jump.",
    ),
    "sonar_no_echo": FaultHelp(
        "the sonar never hears an echo",
        "The ultrasound IP never sees an echo: every range reads 'nothing in range'.",
        "The robot no longer sees obstacles or peers with its sonar: APF repulsion from sonar "
        "echoes stops, and only peers heard on the radio are still avoided.",
    ),
    "pwm_stuck": FaultHelp(
        "hold one wheel's PWM duty",
        "One wheel's PWM output holds DUTY (signed, -1..1) whatever the firmware writes.",
        "The firmware's writes to that channel change nothing: the body is pushed off its "
        "course, and the feedback on the other wheels and the positioning fix fight the drift "
        "(the act messages show the stuck duty).",
    ),
    "pwm_saturated": FaultHelp(
        "drive one wheel's PWM to full duty",
        "One wheel's PWM output is driven to full duty in the direction SIGN.",
        "As a stuck PWM at full duty: the robot is pushed off its course hard; a watchdog "
        "expiry still cuts the outputs.",
    ),
    "fix_cut": FaultHelp(
        "no new positioning fix",
        "The positioning IP gets no new fix (a GNSS or UWB outage).",
        "The robot dead-reckons on its encoders and its estimate drifts until the fix comes "
        "back (`swarm fault clear-registers`).",
    ),
    "watchdog_expire": FaultHelp(
        "expire the watchdog now",
        "The watchdog IP expires now, as if the firmware had stopped kicking it.",
        "The IP cuts every PWM output: the robot stops until its firmware re-arms the watchdog "
        "(docs/registers.md, watchdog).",
    ),
    "tick_slow": FaultHelp(
        "slow every control tick by X ms (CPU overload)",
        "Every control tick of the robot takes EXTRA_MS longer: CPU overload on the board.",
        "In real time the robot misses control deadlines (counted in its telemetry and "
        "summary.json) and steers on late commands; in lockstep it only slows the wall clock, "
        "since the world waits for it.",
    ),
    "clear_registers": FaultHelp(
        "undo every register fault of a robot",
        "Undo every register fault of the robot.",
        "Its IPs behave normally again from the next tick.",
    ),
}

FLAGS: dict[str, str] = {
    "process": "PROCESS",
    "robot": "--robot",
    "link": "--link",
    "latency_ms": "--latency-ms",
    "jitter_ms": "--jitter-ms",
    "loss": "--loss",
    "burst": "--burst",
    "robots": "ROBOTS",
    "wheel": "--wheel",
    "bit": "--bit",
    "value": "--value",
    "duty": "--duty",
    "sign": "--sign",
    "extra_ms": "--extra-ms",
}
"""The argument that sets each field of a fault model."""

BURST_FIELDS = ("good_to_bad", "bad_to_good", "loss_in_good", "loss_in_bad")


def command_name(fault: str) -> str:
    """The subcommand of a fault: `encoder_stuck` -> `encoder-stuck`."""
    return fault.replace("_", "-")


def _link(text: str) -> tuple[str, str]:
    parts = tuple(part.strip() for part in text.split(","))
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"{text!r} is not a link: give two robots, A,B")
    return parts[0], parts[1]


def _burst(text: str) -> dict[str, float]:
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if not 2 <= len(values) <= len(BURST_FIELDS):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a burst model: give GOOD_TO_BAD,BAD_TO_GOOD[,LOSS_IN_GOOD"
            "[,LOSS_IN_BAD]] as numbers"
        )
    return dict(zip(BURST_FIELDS, values, strict=False))


def _add_arguments(name: str, cmd: argparse.ArgumentParser) -> None:
    match name:
        case "kill" | "stop" | "cont" | "restart":
            cmd.add_argument("process", metavar="PROCESS", help=PROCESS_HELP)
        case "net":
            cmd.add_argument("--robot", metavar="R", help="only the links to and from robot R")
            cmd.add_argument(
                "--link", type=_link, metavar="A,B", help="only the link A-B (both directions)"
            )
            cmd.add_argument("--loss", type=float, metavar="P", help="loss probability, 0..1")
            cmd.add_argument("--latency-ms", type=float, metavar="MS", help="mean delay, ms")
            cmd.add_argument(
                "--jitter-ms", type=float, metavar="MS", help="delay spread: mean +- this, ms"
            )
            cmd.add_argument(
                "--burst",
                type=_burst,
                metavar="G2B,B2G[,LG[,LB]]",
                help="Gilbert-Elliott bursts instead of --loss: per-frame probabilities of "
                "going good->bad and bad->good, and the loss in each state (default 0 and 1)",
            )
        case "partition":
            cmd.add_argument("robots", nargs="+", metavar="ROBOT", help="the robots cut off")
        case "heal":
            pass
        case _:
            cmd.add_argument("robot", metavar="ROBOT", help="the robot whose FPGA model it hits")
            model = FAULT_MODELS[name]
            if "wheel" in model.model_fields:
                cmd.add_argument("--wheel", type=int, required=True, metavar="W", help="wheel 0-3")
            if name == "encoder_bit_stuck":
                cmd.add_argument(
                    "--bit", type=int, required=True, metavar="B", help="bit 0-31 of the count"
                )
                cmd.add_argument(
                    "--value", type=int, required=True, metavar="0|1", help="what it reads"
                )
            if name == "pwm_stuck":
                cmd.add_argument(
                    "--duty", type=float, required=True, metavar="D", help="signed duty, -1..1"
                )
            if name == "pwm_saturated":
                cmd.add_argument(
                    "--sign", type=int, metavar="-1|1", help="direction (default 1, forward)"
                )
            if name == "tick_slow":
                cmd.add_argument(
                    "--extra-ms",
                    type=float,
                    required=True,
                    metavar="X",
                    help="milliseconds added to every control tick",
                )


HELP_WIDTH = 78


def _paragraphs(*paragraphs: str) -> str:
    """Paragraphs filled to the help's width (for RawDescriptionHelpFormatter); one that
    starts with two spaces is kept as it is."""
    return "\n\n".join(
        p if p.startswith("  ") else textwrap.fill(p, HELP_WIDTH) for p in paragraphs
    )


def _description(name: str) -> str:
    text = FAULT_HELP[name]
    return _paragraphs(text.does, f"What the swarm does: {text.swarm}")


def add_fault_parser(
    sub: argparse._SubParsersAction[argparse.ArgumentParser],
    options: Callable[[argparse.ArgumentParser, bool], None],
    handler: Callable[[argparse.Namespace], int],
) -> argparse.ArgumentParser:
    """`swarm fault` and its subcommands.  options(parser, suppress_defaults) adds the admin
    query options (--swarm, --connect, ...): given before or after the subcommand."""
    kinds = (
        ("process", "kill, stop, cont, restart"),
        ("network", "net, partition, heal"),
        ("register", ", ".join(command_name(fault_name(m)) for m in REGISTER_FAULTS)),
    )
    fault = sub.add_parser(
        "fault",
        help="inject a fault into a running swarm (process, network or register)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_paragraphs(
            "Inject one fault into a running swarm through the world's admin verb `fault`: the "
            "world applies it at a tick boundary and records it, with its simulation time, in "
            "DIR/events.jsonl (with what follows: robot down and up, leader changes). Bad input "
            "is refused with the field named, and nothing is sent.",
            "\n".join(
                textwrap.fill(
                    names,
                    HELP_WIDTH,
                    initial_indent=f"  {kind:<9} ",
                    subsequent_indent=" " * 12,
                    break_on_hyphens=False,
                )
                for kind, names in kinds
            ),
            "`swarm fault FAULT --help` says what each does and what the swarm does about it. "
            """`swarm fault --json '{"fault": "pwm_stuck", "robot": "robot2", "wheel": 0, """
            """"duty": 0.5}'` takes any fault as the JSON of a scenario's faults: list. A """
            "process fault that the world does not answer (it is down or frozen) goes to the "
            "launcher directly.",
        ),
    )
    fault.add_argument(
        "--json", metavar="JSON", dest="fault_json", help="the fault as one JSON object"
    )
    fault.add_argument(
        "--dry-run",
        action="store_true",
        help="print the fault's JSON and send nothing",
    )
    options(fault, False)
    fault.set_defaults(handler=handler, fault_name=None)
    faults = fault.add_subparsers(dest="fault_command", metavar="FAULT")
    for name in FAULT_NAMES:
        text = FAULT_HELP[name]
        aliases = [name] if command_name(name) != name else []
        cmd = faults.add_parser(
            command_name(name),
            aliases=aliases,
            help=text.summary,
            description=_description(name),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        _add_arguments(name, cmd)
        cmd.add_argument(
            "--dry-run",
            action="store_true",
            default=argparse.SUPPRESS,
            help="print the fault's JSON and send nothing",
        )
        options(cmd, True)
        cmd.set_defaults(fault_name=name)
    return fault


def _describe(error: ValidationError, flags: Mapping[str, str] | None) -> str:
    """'invalid fault:' and one line per problem, naming the field (and the flag that sets it);
    the discriminator's tag is left out of the field's path."""
    lines = ["invalid fault:"]
    for item in error.errors(include_url=False):
        loc = [str(part) for part in item["loc"]]
        if loc and loc[0] in FAULT_MODELS:
            loc = loc[1:]
        where = ".".join(loc) or "(the fault)"
        flag = flags.get(loc[0]) if flags and loc else None
        hint = f" ({flag})" if flag else ""
        lines.append(f"  {where}{hint}: {item['msg'].removeprefix('Value error, ')}")
    return "\n".join(lines)


def fault_from_json(text: str) -> Fault:
    """The fault of `swarm fault --json TEXT`."""
    try:
        data: Any = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise FaultArgumentError(f"--json is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise FaultArgumentError("--json must be one JSON object with a 'fault' field")
    if data.get("fault") not in FAULT_MODELS:
        raise FaultArgumentError(
            f"fault: {data.get('fault')!r} is not a fault; use one of {', '.join(FAULT_NAMES)}"
        )
    booleans = fault_boolean_problems(data)
    if booleans:  # pydantic would take true for 1: `"extra_ms": true` was 1 ms
        raise FaultArgumentError(f"--json: {booleans[0]}")
    try:
        return FAULT_ADAPTER.validate_python(data)
    except ValidationError as exc:
        raise FaultArgumentError(_describe(exc, None)) from None


def fault_from_args(args: argparse.Namespace) -> Fault:
    """The fault the parsed `swarm fault` arguments describe."""
    given_json = getattr(args, "fault_json", None)
    name = getattr(args, "fault_name", None)
    if given_json is not None:
        if name is not None:
            raise FaultArgumentError("give a fault subcommand or --json, not both")
        return fault_from_json(given_json)
    if name is None:
        raise FaultArgumentError(
            f"name a fault ({', '.join(command_name(n) for n in FAULT_NAMES)}) or give --json"
        )
    model = FAULT_MODELS[name]
    data: dict[str, object] = {"fault": name}
    for field in model.model_fields:
        value = getattr(args, field, None)
        if field != "fault" and value is not None:
            data[field] = value
    try:
        return FAULT_ADAPTER.validate_python(data)
    except ValidationError as exc:
        raise FaultArgumentError(_describe(exc, FLAGS)) from None


def fault_json(fault: Fault) -> bytes:
    """The fault as the world's `fault` verb reads it."""
    return FAULT_ADAPTER.dump_json(fault, exclude_none=True)

"""The checks that scripts/compose-smoke.sh runs against the compose stack, as one command line.

    python -m tests.support.compose_checks live      --connect EP [--timeout S]
    python -m tests.support.compose_checks formation --connect EP [--max-error-m M --hold S ...]
    python -m tests.support.compose_checks gone      --connect EP --robot R [--observe S]
    python -m tests.support.compose_checks rejoin    --connect EP --robot R [--hold S ...]
    python -m tests.support.compose_checks final     --connect EP
    python -m tests.support.compose_checks viewer    URL [--timeout S]
    python -m tests.support.compose_checks grpc      HOST:PORT [--timeout S]
    python -m tests.support.compose_checks summary   SUMMARY_JSON [--min-duration S]

The swarm checks ask the world for its admin status (`swarm/<swarm>/admin/world/status`,
world/runtime.py) through the router's published port, over one client session, and read its
reply as `WorldStatusReply` (robot_firmware/net/messages.py):

* live: every robot of --robots is live;
* formation: every robot live with its position error (distance from its reference: the
  trajectory for the leader, its slot of eq. 17 for a follower) under --max-error-m for --hold s
  in a row, and no collision, within --timeout s;
* gone: after a kill, the world sees --robot leave within 10 s; --observe s later the others are
  still live, it stays down, the world's clock advanced at least half as much as the wall's,
  no collision, and the leader on its trajectory, or back on it within 15 s more: a leader
  going round the scenario's obstacle is off it for seconds every lap (the paper's: up to 87 cm
  for 4 s of its 18 s lap), longer where the killed robot's braked body blocks the way round;
* rejoin: --robot is live again within 20 s of its restart, then the formation holds as above
  (--timeout counts from the start of the check);
* final: the world answers and reports no collision.

`viewer` checks that the web viewer answers HTTP 200; `grpc` that the dashboard's data port
answers the HTTP/2 preface with a SETTINGS frame, as a gRPC server does (through Docker's
published port, a server listening on the container's loopback only is connected and then cut
off: a TCP connection alone proves nothing); `summary` prints the figures of a world's
summary.json and, with --min-duration, judges it (ran longer than that, no collision).

Progress lines are indented; a failed check ends with one "CHECK FAILED: ..." line. Exit status
0 when the check passed, 1 when it failed, 2 for a usage error, 3 when no verdict came in time
(a hung Zenoh call; a watchdog ends the process).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import LoopTimingReport, WorldStatusReply, parse_reply
from robot_firmware.net.session import open_client
from tests.support.compose_host import http_status
from tests.support.waiting import wait_for

T = TypeVar("T")

GONE_WITHIN_S = 10.0
"""How soon after a kill the world must stop listing the robot as live."""
LEADER_BACK_WITHIN_S = 15.0
"""How long after the observation a leader off its trajectory may take to be back on it: a
detour round an obstacle, or round the killed robot's body where it blocks the way, lasts a few
seconds (the paper's lap takes 18 s: its obstacle detour about 4 s of it, up to 8 s when the
braked body of the killed follower lies beside the way round)."""
LIVE_AGAIN_WITHIN_S = 20.0
"""How soon after a restart the world must list the robot as live again."""
SHOW_EVERY_S = 5.0
"""Period of the progress lines while a formation settles."""
WATCHDOG_MARGIN_S = 30.0
"""Added to a check's own time budget before the watchdog ends the process."""
EXIT_PASSED, EXIT_FAILED, EXIT_HUNG = 0, 1, 3
"""Exit statuses; argparse exits with 2 for a usage error."""


class CheckFailedError(Exception):
    """A check's verdict: the message is the text of the CHECK FAILED line."""


# -- what the checks read ---------------------------------------------------------------------


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CheckFailedError(f"no number for {what}: {value!r}")
    return float(value)


def read_world_status(payload: bytes) -> WorldStatusReply | None:
    """The world's status reply; None when the world refused; CheckFailedError when it does
    not fit the model."""
    reply = parse_reply(WorldStatusReply, payload)
    if reply is None:
        raise CheckFailedError(f"the world's status reply does not fit: {payload[:300]!r}")
    return reply if isinstance(reply, WorldStatusReply) else None


def position_error_m(status: WorldStatusReply, robot: str) -> float:
    """The robot's position error; infinite when the world reports none for it."""
    return status.position_errors_m.get(robot, math.inf)


StatusSource = Callable[[], WorldStatusReply | None]


@contextmanager
def world_status_source(
    swarm: str, endpoint: str, reply_timeout_s: float = 2.0
) -> Iterator[StatusSource]:
    """A client session to the router at `endpoint` (it waits for the router, as every swarm
    process does) and, while it is open, a source that asks the world of `swarm` for its
    status, one admin query a call (None when nobody answered)."""
    key = SwarmKeys(swarm).admin("world", "status")
    with open_client([endpoint]) as session:

        def status() -> WorldStatusReply | None:
            for reply in session.get(key, timeout=reply_timeout_s):
                if reply.ok is not None:
                    return read_world_status(bytes(reply.ok.payload.to_bytes()))
            return None

        yield status


# -- the pure parts -----------------------------------------------------------------------------


@dataclass
class FormationHold:
    """Whether the formation has held: every robot live with its position error under
    `max_error_m` for `hold_s` in a row. No answer, a robot not live or an error at or over the
    bound starts the count again."""

    robots: tuple[str, ...]
    max_error_m: float
    hold_s: float
    since_s: float | None = None

    def settled(self, status: WorldStatusReply) -> bool:
        return all(
            n in status.live and position_error_m(status, n) < self.max_error_m for n in self.robots
        )

    def update(self, now_s: float, status: WorldStatusReply | None) -> bool:
        """Takes the status seen at `now_s`; True once the formation has held for hold_s."""
        if status is None or not self.settled(status):
            self.since_s = None
            return False
        if self.since_s is None:
            self.since_s = now_s
        return now_s - self.since_s >= self.hold_s


def after_kill_problems(
    before: WorldStatusReply,
    after: WorldStatusReply,
    dead: str,
    robots: Sequence[str],
    observe_s: float,
) -> list[str]:
    """What is wrong `observe_s` after the world saw `dead` leave (`before`), in `after`; the
    leader's tracking is judged apart (`check_gone`)."""
    others = [n for n in robots if n != dead]
    advanced_s = after.t_s - before.t_s
    problems = []
    if not set(others) <= set(after.live):
        problems.append(f"{', '.join(others)} did not all stay live")
    if dead in after.live:
        problems.append(f"{dead} came back by itself (its restart policy should be 'no')")
    if advanced_s < 0.5 * observe_s:
        problems.append(f"the world advanced only {advanced_s:.1f} s in {observe_s:g} s")
    if after.metrics.collisions:
        problems.append(f"the world reports {after.metrics.collisions} collisions")
    return problems


FIGURES_M = {
    "formation_rms_m": "formation RMS",
    "leader_tracking_rms_m": "leader RMS",
    "min_robot_separation_m": "min robot separation",
    "min_obstacle_clearance_m": "min obstacle clearance",
}
"""The run's figures in metres that the reports show (world/metrics.py), and their labels."""


def format_figures_m(figures: Mapping[str, object]) -> str:
    return ", ".join(f"{label} {format_figure_m(figures.get(k))}" for k, label in FIGURES_M.items())


def format_figure_m(value: object) -> str:
    """A figure in metres as the summary holds it: a number, a map per robot, or none."""
    if isinstance(value, bool) or value is None:
        return "n/a"
    if isinstance(value, int | float):
        return f"{value:.3f} m"
    if isinstance(value, Mapping):
        if not value:
            return "n/a"
        return ", ".join(f"{name} {format_figure_m(v)}" for name, v in value.items())
    return str(value)


# -- the checks -------------------------------------------------------------------------------


@dataclass
class Probe:
    """What every swarm check uses: the world's status, the time, and the progress lines."""

    source: StatusSource
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    last: WorldStatusReply | None = None
    t0_s: float = field(init=False)

    def __post_init__(self) -> None:
        self.t0_s = self.clock()

    def elapsed_s(self) -> float:
        return self.clock() - self.t0_s

    def status(self) -> WorldStatusReply | None:
        status = self.source()
        if status is not None:
            self.last = status
        return status

    def show(self, status: WorldStatusReply) -> None:
        errors = ", ".join(f"{n} {100 * e:.1f}" for n, e in status.position_errors_m.items())
        print(
            f"    +{self.elapsed_s():5.1f} s  world t={status.t_s:6.1f} s  "
            f"live {','.join(status.live) or '-'}  errors [cm] {errors}  "
            f"collisions {status.metrics.collisions}",
            flush=True,
        )

    def wait(
        self, predicate: Callable[[], T | None], timeout_s: float, every_s: float, failure: str
    ) -> T:
        """wait_for on this probe's clock; on time-out the last answer, then CheckFailedError."""
        try:
            return wait_for(
                predicate,
                max(timeout_s, 0.0),
                every_s,
                describe=failure,
                clock=self.clock,
                sleep=self.sleep,
            )
        except AssertionError as exc:
            if self.last is not None:
                self.show(self.last)
            else:
                print("    the world never answered")
            raise CheckFailedError(failure) from exc


def check_live(probe: Probe, robots: Sequence[str], timeout_s: float) -> None:
    def all_live() -> WorldStatusReply | None:
        status = probe.status()
        return status if status is not None and set(robots) <= set(status.live) else None

    names = ", ".join(robots)
    status = probe.wait(all_live, timeout_s, 0.5, f"{names} not all live within {timeout_s:g} s")
    probe.show(status)
    print(f"    the world sees {names} live, {probe.elapsed_s():.1f} s")


def hold_formation(
    probe: Probe,
    robots: Sequence[str],
    max_error_m: float,
    hold_s: float,
    timeout_s: float,
    what: str,
) -> None:
    """The formation holds within `timeout_s` of the start of the check; a collision fails it
    at once."""
    hold = FormationHold(tuple(robots), max_error_m, hold_s)
    shown_s = -math.inf

    def held() -> WorldStatusReply | None:
        nonlocal shown_s
        status = probe.status()
        now_s = probe.clock()
        if status is None:
            hold.update(now_s, None)
            return None
        if status.metrics.collisions:
            probe.show(status)
            raise CheckFailedError(
                f"{what}: the world reports {status.metrics.collisions} collisions"
            )
        if now_s - shown_s >= SHOW_EVERY_S:
            probe.show(status)
            shown_s = now_s
        return status if hold.update(now_s, status) else None

    bound_cm = f"{100 * max_error_m:g} cm"
    failure = (
        f"{what}: the position errors of {', '.join(robots)} were not all under {bound_cm} "
        f"for {hold_s:g} s within {timeout_s:g} s"
    )
    status = probe.wait(held, timeout_s - probe.elapsed_s(), 0.5, failure)
    probe.show(status)
    print(
        f"    {what}: every position error < {bound_cm} for {hold_s:g} s, "
        f"{probe.elapsed_s():.1f} s after the start of the check"
    )


def check_gone(
    probe: Probe, robots: Sequence[str], dead: str, observe_s: float, max_error_m: float
) -> None:
    def left() -> WorldStatusReply | None:
        status = probe.status()
        return status if status is not None and dead not in status.live else None

    failure = f"the world still lists {dead} as live {GONE_WITHIN_S:g} s after the kill"
    before = probe.wait(left, GONE_WITHIN_S, 0.2, failure)
    probe.show(before)
    print(f"    the world saw {dead} leave within {probe.elapsed_s():.1f} s")
    probe.sleep(observe_s)
    after = probe.status()
    if after is None:
        raise CheckFailedError("the world stopped answering after the kill")
    probe.show(after)
    problems = after_kill_problems(before, after, dead, robots, observe_s)
    if problems:
        raise CheckFailedError(f"after the kill of {dead}: {'; '.join(problems)}")
    leader = robots[0]
    if leader != dead and position_error_m(after, leader) >= max_error_m:
        print(
            f"    the leader {leader} is {100 * position_error_m(after, leader):.1f} cm off its "
            f"trajectory: waiting up to {LEADER_BACK_WITHIN_S:g} s for it to be back on it"
        )

        def leader_back() -> WorldStatusReply | None:
            status = probe.status()
            if status is None or position_error_m(status, leader) >= max_error_m:
                return None
            return status

        failure = (
            f"after the kill of {dead}: the leader {leader} left its trajectory (not back on "
            f"it within {LEADER_BACK_WITHIN_S:g} s)"
        )
        after = probe.wait(leader_back, LEADER_BACK_WITHIN_S, 0.2, failure)
        probe.show(after)
        problems = after_kill_problems(before, after, dead, robots, observe_s)
        if problems:
            raise CheckFailedError(f"after the kill of {dead}: {'; '.join(problems)}")
    others = ", ".join(n for n in robots if n != dead)
    print(
        f"    {others} kept going: {after.t_s - before.t_s:.1f} s of world time in "
        f"{observe_s:g} s, leader error {100 * position_error_m(after, robots[0]):.1f} cm"
    )


def check_rejoin(
    probe: Probe,
    robots: Sequence[str],
    robot: str,
    max_error_m: float,
    hold_s: float,
    timeout_s: float,
) -> None:
    def live_again() -> WorldStatusReply | None:
        status = probe.status()
        return status if status is not None and robot in status.live else None

    failure = f"{robot} not live within {LIVE_AGAIN_WITHIN_S:g} s of its restart"
    probe.wait(live_again, LIVE_AGAIN_WITHIN_S, 0.2, failure)
    print(f"    {robot} live again {probe.elapsed_s():.1f} s after its restart")
    hold_formation(probe, robots, max_error_m, hold_s, timeout_s, f"{robot} rejoined")


def check_final(probe: Probe, timeout_s: float) -> None:
    status = probe.wait(probe.status, timeout_s, 0.5, "the world does not answer")
    collisions = status.metrics.collisions
    print(
        f"    world t={status.t_s:.1f} s, collisions {collisions}, "
        f"{format_figures_m(status.metrics.model_dump())}"
    )
    if collisions:
        raise CheckFailedError(f"the world reports {collisions} collisions")


def check_viewer(
    url: str,
    timeout_s: float,
    status_of: Callable[[str, float], int | None] = http_status,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> None:
    codes: list[int | None] = []

    def serves() -> bool:
        codes.append(status_of(url, 5.0))
        return codes[-1] == 200

    try:
        wait_for(serves, timeout_s, 0.5, describe=url, clock=clock, sleep=sleep)
    except AssertionError as exc:
        code = "none" if codes[-1] is None else codes[-1]
        raise CheckFailedError(f"no web viewer at {url} (HTTP status: {code})") from exc
    print(f"    the web viewer answers at {url} (HTTP 200)")


HTTP2_CLIENT_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
HTTP2_FRAME_HEADER_BYTES = 9
HTTP2_SETTINGS = 0x4
HTTP2_EMPTY_SETTINGS_FRAME = bytes([0, 0, 0, HTTP2_SETTINGS, 0, 0, 0, 0, 0])


def http2_answer_problem(address: tuple[str, int], timeout_s: float) -> str | None:
    """None when the server at `address` answers an HTTP/2 client preface with a SETTINGS
    frame (what a gRPC server sends first); otherwise what happened instead."""
    header = b""
    try:
        with socket.create_connection(address, timeout=timeout_s) as connection:
            connection.settimeout(timeout_s)
            connection.sendall(HTTP2_CLIENT_PREFACE + HTTP2_EMPTY_SETTINGS_FRAME)
            while len(header) < HTTP2_FRAME_HEADER_BYTES:
                chunk = connection.recv(HTTP2_FRAME_HEADER_BYTES - len(header))
                if not chunk:
                    return f"the connection closed after {len(header)} bytes"
                header += chunk
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    if header[3] != HTTP2_SETTINGS:
        return f"the answer began {header.hex()}, not with an HTTP/2 SETTINGS frame"
    return None


def check_grpc(
    address: tuple[str, int],
    timeout_s: float,
    problem_of: Callable[[tuple[str, int], float], str | None] = http2_answer_problem,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> None:
    problems: list[str | None] = []

    def answers() -> bool:
        problems.append(problem_of(address, 5.0))
        return problems[-1] is None

    where = f"{address[0]}:{address[1]}"
    try:
        wait_for(answers, timeout_s, 0.5, describe=where, clock=clock, sleep=sleep)
    except AssertionError as exc:
        raise CheckFailedError(f"no gRPC server at {where} ({problems[-1]})") from exc
    print(f"    a gRPC (HTTP/2) server answers at {where}")


def _host_port(text: str) -> tuple[str, int]:
    host, colon, port = text.rpartition(":")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host, int(port)


# -- summary.json -------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSummary:
    """The fields of a world's summary.json (docs/summary-schema.md) that the report shows."""

    duration_s: float
    collisions: int
    clock_mode: str
    figures_m: Mapping[str, object]
    control_timing: Mapping[str, LoopTimingReport | None]

    @classmethod
    def read(cls, path: Path) -> RunSummary:
        """CheckFailedError when the file is missing, not JSON or lacks a field."""
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            timing = data.get("control_timing") or {}
            return cls(
                duration_s=_number(data.get("duration_s"), "duration_s"),
                collisions=int(_number(data.get("collisions"), "collisions")),
                clock_mode=str(data.get("clock_mode", "?")),
                figures_m={key: data.get(key) for key in FIGURES_M},
                control_timing={
                    str(name): LoopTimingReport.model_validate(t) if t else None
                    for name, t in timing.items()
                },
            )
        except (OSError, ValueError, TypeError, AttributeError, CheckFailedError) as exc:
            # (a pydantic ValidationError is a ValueError)
            raise CheckFailedError(f"cannot read {path}: {exc}") from exc

    def report_lines(self) -> list[str]:
        lines = [
            f"world summary: {self.duration_s:.1f} s simulated ({self.clock_mode}), "
            f"collisions {self.collisions}, {format_figures_m(self.figures_m)}"
        ]
        for name, t in self.control_timing.items():
            if t is None:
                lines.append(f"{name}: no control timing")
                continue
            jitter = "n/a" if t.period_jitter_p99_ms is None else f"{t.period_jitter_p99_ms:.1f} ms"
            lines.append(
                f"{name}: {t.deadline_misses} of {t.ticks} control deadlines missed, "
                f"period jitter p99 {jitter}"
            )
        return lines

    def problems(self, min_duration_s: float) -> list[str]:
        problems = []
        if self.duration_s <= min_duration_s:
            problems.append(
                f"the world ran {self.duration_s:.1f} s, not more than {min_duration_s:g} s"
            )
        if self.collisions:
            problems.append(f"{self.collisions} collisions")
        return problems


def report_summary(path: Path, min_duration_s: float | None) -> None:
    summary = RunSummary.read(path)
    for line in summary.report_lines():
        print(f"    {line}")
    if min_duration_s is not None and (problems := summary.problems(min_duration_s)):
        raise CheckFailedError(f"{path.name}: {'; '.join(problems)}")


# -- command line -------------------------------------------------------------------------------


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a positive number, not {text}")
    return value


def _robot_names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"need distinct robot names separated by commas: {text!r}")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tests.support.compose_checks",
        description="Checks of the compose stack against the world's admin status.",
    )
    sub = parser.add_subparsers(dest="check", required=True, metavar="CHECK")
    swarm = argparse.ArgumentParser(add_help=False)
    swarm.add_argument("--connect", required=True, help="the router's endpoint, tcp/HOST:PORT")
    swarm.add_argument("--swarm", default="lab", help="the swarm's name (default lab)")
    swarm.add_argument(
        "--robots",
        type=_robot_names,
        default=["robot1", "robot2", "robot3"],
        help="the robots, leader first (default robot1,robot2,robot3)",
    )
    error = argparse.ArgumentParser(add_help=False)
    error.add_argument(
        "--max-error-m", type=_positive, default=0.05, help="position error bound (default 0.05)"
    )
    robot = argparse.ArgumentParser(add_help=False)
    robot.add_argument("--robot", default="robot2", help="the robot killed or restarted")

    def timeout(p: argparse.ArgumentParser, default_s: float) -> None:
        p.add_argument(
            "--timeout", type=_positive, default=default_s, help=f"seconds (default {default_s:g})"
        )

    def hold(p: argparse.ArgumentParser, default_s: float) -> None:
        p.add_argument(
            "--hold",
            type=_positive,
            default=default_s,
            help=f"seconds in a row under the bound (default {default_s:g})",
        )

    live = sub.add_parser("live", parents=[swarm], help="every robot live")
    timeout(live, 60.0)
    formation = sub.add_parser("formation", parents=[swarm, error], help="the formation holds")
    hold(formation, 3.0)
    timeout(formation, 60.0)
    gone = sub.add_parser("gone", parents=[swarm, error, robot], help="a killed robot stays gone")
    gone.add_argument(
        "--observe", type=_positive, default=5.0, help="seconds to watch the others (default 5)"
    )
    rejoin = sub.add_parser("rejoin", parents=[swarm, error, robot], help="a robot rejoins")
    hold(rejoin, 2.0)
    timeout(rejoin, 45.0)
    final = sub.add_parser("final", parents=[swarm], help="the world answers, no collision")
    timeout(final, 10.0)
    viewer = sub.add_parser("viewer", help="the web viewer answers HTTP 200")
    viewer.add_argument("url")
    timeout(viewer, 10.0)
    grpc = sub.add_parser("grpc", help="a gRPC (HTTP/2) server answers at HOST:PORT")
    grpc.add_argument("address", type=_host_port, metavar="HOST:PORT")
    timeout(grpc, 10.0)
    summary = sub.add_parser("summary", help="the figures of a world's summary.json")
    summary.add_argument("path", type=Path)
    summary.add_argument(
        "--min-duration",
        type=_positive,
        help="fail unless the world ran longer than this many seconds without a collision",
    )
    return parser


def _budget_s(args: argparse.Namespace) -> float:
    """The longest a swarm check may take before its watchdog ends it."""
    budget_s = float(args.timeout) if "timeout" in args else GONE_WITHIN_S
    if args.check == "gone":
        budget_s = GONE_WITHIN_S + args.observe + LEADER_BACK_WITHIN_S
    if args.check == "rejoin":
        budget_s += LIVE_AGAIN_WITHIN_S
    return budget_s + WATCHDOG_MARGIN_S


def _start_watchdog(budget_s: float, endpoint: str) -> threading.Timer:
    def hung() -> None:
        print(
            f"CHECK FAILED: no verdict within {budget_s:g} s (no router at {endpoint}, "
            "or a Zenoh call hung)",
            flush=True,
        )
        os._exit(EXIT_HUNG)

    watchdog = threading.Timer(budget_s, hung)
    watchdog.daemon = True
    watchdog.start()
    return watchdog


def run_check(args: argparse.Namespace, probe: Probe) -> None:
    robots: list[str] = args.robots
    if args.check == "live":
        check_live(probe, robots, args.timeout)
    elif args.check == "formation":
        hold_formation(probe, robots, args.max_error_m, args.hold, args.timeout, "formation")
    elif args.check == "gone":
        check_gone(probe, robots, args.robot, args.observe, args.max_error_m)
    elif args.check == "rejoin":
        check_rejoin(probe, robots, args.robot, args.max_error_m, args.hold, args.timeout)
    else:
        check_final(probe, args.timeout)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if "robot" in args and args.robot not in args.robots:
        parser.error(f"--robot {args.robot} is not one of --robots {','.join(args.robots)}")
    try:
        if args.check == "viewer":
            check_viewer(args.url, args.timeout)
        elif args.check == "grpc":
            check_grpc(args.address, args.timeout)
        elif args.check == "summary":
            report_summary(args.path, args.min_duration)
        else:
            watchdog = _start_watchdog(_budget_s(args), args.connect)
            try:
                with world_status_source(args.swarm, args.connect) as source:
                    run_check(args, Probe(source))
            finally:
                watchdog.cancel()
    except CheckFailedError as exc:
        print(f"CHECK FAILED: {exc}", flush=True)
        return EXIT_FAILED
    sys.stdout.flush()
    return EXIT_PASSED


if __name__ == "__main__":
    sys.exit(main())

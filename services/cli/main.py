"""The `swarm` command line.

Subcommands live in their own functions; argument parsing stays here.  A user mistake (bad
scenario, missing file) prints one clear message and exits with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel

from robot_firmware.net.keys import check_name
from robot_firmware.net.session import DEFAULT_ENDPOINT, SessionOpenError, split_endpoints
from services.launcher.orphans import LAUNCHER_PID_ENV, end_with_the_launcher
from services.log_setup import LogLevelError, set_up_logging
from services.output_folder import OutputFolderError, prepare_output_folder
from services.path_arguments import empty_path_problem
from services.real_time_hold import real_time_shortfalls
from services.standard_output import guard_standard_output
from services.stop_signals import (
    EXIT_INTERRUPTED,
    StopOnSignal,
    interrupt_once,
    stop_on_signals,
)
from swarm_config.atomic_files import FileWriteError
from swarm_config.credentials import (
    CREDENTIALS_DIR_NAME,
    CREDENTIALS_FILE_ENV,
    DASHBOARD,
    HOW_TO_GET_CREDENTIALS,
    OPERATOR,
    PRIVATE_DIR_MODE,
    ROUTER,
    SERVICE_IDENTITIES,
    CredentialsError,
    ProcessCredentials,
    read_credentials,
)
from swarm_config.settings import (
    DEFAULT_SCENARIO_PATH,
    LayeredSettings,
    ScenarioError,
    SettingsError,
    endpoint_list,
    positive_seconds,
    read_input_file,
    tcp_port,
)
from swarm_config.tls import (
    DEFAULT_TLS_HOSTS,
    TLS_DIR_NAME,
    TLS_ROOT_CA_ENV,
    TlsError,
    TlsFiles,
    generate_tls_files,
    read_tls_files,
    subject_alt_name,
    tls_dir,
)

EXIT_USAGE = 2
EXIT_WRITE_FAILED = 1
UNUSABLE_PATH_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP})
"""What a file system call answers a path given on the command line that no call can take."""
ROUTER_BACK_WITHIN_S = 20.0
"""How long `swarm fault kill|restart router` waits for the launcher behind the new router."""
KERNELS_ENV = "SWARM_KERNELS"
"""robot_firmware.control.kernels.KERNELS_ENV, spelt out: importing that module settles how
this process runs the kernels, which `_run_jit_kernels` must do first."""
JIT_KERNEL_COMMANDS = frozenset({"sim", "tune", "world"})
"""The commands whose own numba kernels call the control kernels (the batch simulator's, the
world's): they need numba's JIT for those, whatever $SWARM_KERNELS says (`aot` is a robot
process's setting; robot_firmware/control/kernels.py)."""


class UsageError(Exception):
    """A user mistake or an unreachable swarm, reported in one line without a traceback."""


DEFAULT_SCENARIO = str(DEFAULT_SCENARIO_PATH)
DEFAULT_TLS_ENDPOINT = "tls/127.0.0.1:7447"
DEFAULT_OPERATOR_CREDENTIALS = Path("runs/swarm") / CREDENTIALS_DIR_NAME / f"{OPERATOR}.json"
MAX_SPEED_HELP = (
    "with --lockstep: run at most X simulated seconds per wall second, e.g. 1 to watch a "
    "deterministic run at real speed (default: as fast as the robots answer)"
)


def _cmd_sim(args: argparse.Namespace) -> int:
    from services.sim.run import output_names, simulate_scenario
    from swarm_config.scenario import load_scenario, parse_scenario

    scenario = load_scenario(Path(args.scenario))
    updates: dict[str, object] = {}
    if args.seed is not None:
        updates["seed"] = args.seed
    if args.duration is not None:
        updates["duration_s"] = args.duration
    if updates:
        # A bad --seed or --duration is named like a bad field of the file (ScenarioError).
        given = " and ".join(
            f"--{name}" for name in ("seed", "duration") if getattr(args, name) is not None
        )
        scenario = parse_scenario(
            {**scenario.model_dump(), **updates}, f"{args.scenario} with {given}"
        )
    out_dir = prepare_output_folder(
        Path(args.out), "--out", writes=output_names(figures=not args.no_figures)
    )
    outputs = simulate_scenario(
        scenario, out_dir, compare=not args.no_compare, figures=not args.no_figures
    )
    s = outputs.summary
    print(f"scenario {s['scenario']} (seed {s['seed']}, {s['duration_s']} s, {s['controller']})")
    _print_headline(s)
    comparison = s.get("comparison")
    if isinstance(comparison, dict):
        for label, entry in comparison.items():
            # A scenario of the leader alone has no formation error to give.
            formation = ", ".join(_cm(v) for v in entry["formation_rms_m"].values()) or "n/a"
            print(
                f"  {label:<20} leader {_cm(entry['leader_tracking_rms_m'])}, formation "
                f"{formation}, fitness (16) {_db(entry['fitness_snr_db'])}"
            )
    print(f"wrote {outputs.summary_path}")
    for path in outputs.figure_paths:
        print(f"wrote {path}")
    return 0


def _install_stop(stop: threading.Event) -> StopOnSignal:
    """SIGTERM, SIGINT and SIGHUP set `stop` (services/stop_signals.py: without a deadlock
    when they come in a burst); the handler says which came first."""
    return stop_on_signals(stop)


def _cmd_router(args: argparse.Namespace) -> int:
    from services.router.main import run_router

    return run_router(args.listen, Path(args.config) if args.config else None)


def _cmd_world(args: argparse.Namespace) -> int:
    from swarm_config.scenario import load_scenario
    from world.runtime import WorldConfig, WorldProcess

    given = {
        "swarm": args.swarm,
        "scenario": args.scenario,
        "connect": split_endpoints(args.connect) if args.connect else None,
        "lockstep": True if args.lockstep else None,
        "duration_s": args.duration,
        "out_dir": args.out,
        "radio_profile": args.radio,
        "max_speed": args.max_speed,
        "credentials": args.credentials,
    }
    config = _settings(WorldConfig, given, args.config)
    if config.credentials is None:
        raise UsageError(f"no credentials: {HOW_TO_GET_CREDENTIALS}")
    scenario = load_scenario(config.scenario)
    problem = config.scenario_problem(scenario)
    if problem is not None:
        raise UsageError(problem)
    world = WorldProcess(config, scenario)
    stopped_by = _install_stop(world.stop)
    code = world.run()
    if (
        code == 0
        and stopped_by.signum is not None
        and not world.ran_to_its_end
        and os.environ.get(LAUNCHER_PID_ENV)
    ):
        # Under `swarm up`, a world a signal ended before its run did says so by its status
        # (128 + the signal, as a shell reports it): from outside the launcher, that is a
        # death, and the launcher starts it again.  On its own, and under compose, whose
        # `stop` is a SIGTERM, the world's end is the run's: status 0.
        return 128 + stopped_by.signum
    return code


def _cmd_robot(args: argparse.Namespace) -> int:
    from robot_firmware.runtime import RobotConfig, RobotProcess

    given = {
        "name": args.name,
        "swarm": args.swarm,
        "scenario": args.scenario,
        "connect": split_endpoints(args.connect) if args.connect else None,
        "credentials": args.credentials,
    }
    robot = RobotProcess(_settings(RobotConfig, given, args.config))
    _install_stop(robot.stop)
    return robot.run()


S = TypeVar("S", bound=LayeredSettings)


def _settings(
    kind: type[S],
    given: dict[str, object],
    config_file: str | None,
    environ: dict[str, str] | None = None,
) -> S:
    """A process's settings from its YAML file, the environment and the flags; a bad one is
    a usage error naming the field (and its variable)."""
    try:
        return kind.from_sources(
            given, environ, config_file=Path(config_file) if config_file else None
        )
    except SettingsError as exc:
        raise UsageError(str(exc)) from None


def _cmd_credentials(args: argparse.Namespace) -> int:
    """Write a credentials set for a scenario's robots into DIR: keep the secrets of a complete
    set already there (unless --rotate), always with a new run id."""
    from services.launcher.run_lock import RunDirectoryBusyError, RunDirectoryLock

    scenario_file = Path(args.scenario or os.environ.get("SWARM_SCENARIO", DEFAULT_SCENARIO))
    directory = Path(args.dir)
    lock = None
    if directory.is_dir():  # a directory a live `swarm up` writes into is left alone
        prepare_output_folder(directory, "DIR")  # one line naming DIR, before its lock file
        try:
            lock = RunDirectoryLock.acquire(directory, "credentials directory", "DIR")
        except RunDirectoryBusyError as exc:
            raise UsageError(str(exc)) from None
    try:
        return _write_credentials(args, scenario_file, directory)
    finally:
        if lock is not None:
            lock.release()


def _write_credentials(args: argparse.Namespace, scenario_file: Path, directory: Path) -> int:
    from services.router.access import write_router_config
    from swarm_config.credentials import (
        generate_credential_set,
        read_credential_set,
        write_credential_set,
    )
    from swarm_config.scenario import load_scenario

    scenario = load_scenario(scenario_file)
    swarm = _swarm(args)
    listen = args.listen or [DEFAULT_TLS_ENDPOINT if args.tls else DEFAULT_ENDPOINT]
    prepare_output_folder(directory, "DIR", mode=PRIVATE_DIR_MODE)
    try:
        tls_files, tls_note = _tls_files_for(args, directory, swarm, listen)
    except TlsError as exc:
        raise UsageError(str(exc)) from None
    kept = False
    credentials = generate_credential_set(swarm, scenario.robot_names)
    if not args.rotate and directory.exists():
        try:
            existing = read_credential_set(directory, scenario.robot_names)
        except CredentialsError:
            existing = None
        if existing is not None and existing.swarm == swarm:
            credentials, kept = existing.with_new_run_id(), True
    write_credential_set(directory, credentials)
    write_router_config(directory, credentials, listen, tls_files)
    what = "kept the secrets, new run id" if kept else "new secrets"
    print(f"credentials for {', '.join(credentials.identities)} in {directory} ({what})")
    if tls_files is not None:
        print(
            f"TLS: {tls_note}; router certificate {tls_files.router_certificate}, CA "
            f"{tls_files.ca_certificate} (every client trusts it: ${TLS_ROOT_CA_ENV}=<its path>)"
        )
    return 0


def _tls_files_for(
    args: argparse.Namespace, directory: Path, swarm: str, listen: Sequence[str]
) -> tuple[TlsFiles | None, str]:
    """`swarm credentials --tls`: the TLS files kept (unless --rotate) or made in DIR/tls/,
    and what was done; checked before anything is written."""
    if args.tls_host and not args.tls:
        raise TlsError("--tls-host is for the router certificate of --tls")
    if not args.tls:
        if any(endpoint.startswith("tls/") for endpoint in listen):
            raise TlsError("a tls/ --listen endpoint needs --tls (the router's certificate)")
        return None, ""
    directory_tls = tls_dir(directory)
    if TlsFiles(directory_tls).complete() and not args.rotate:
        if args.tls_host:
            raise TlsError(
                f"{directory_tls} already holds a CA and a router certificate; add --rotate "
                "to replace them with new ones for --tls-host"
            )
        return read_tls_files(directory_tls), "kept the CA and router certificate"
    hosts = args.tls_host or list(DEFAULT_TLS_HOSTS)
    files = generate_tls_files(directory_tls, swarm, hosts)
    return files, f"new CA, router certificate for {subject_alt_name(hosts)}"


def _only_robots(given: str | None, scenario: str, robots: Sequence[str]) -> tuple[str, ...] | None:
    """`--only robot3,robot4`: the robots to start on this host, in the order given; a name the
    scenario does not have is a usage error naming it."""
    if given is None:
        return None
    listed = [part.strip() for part in given.split(",") if part.strip()]
    names = tuple(dict.fromkeys(listed))
    if not names:
        raise UsageError("--only needs robot names, e.g. --only robot3,robot4")
    if len(names) < len(listed):  # a typo for another robot, more likely than a repeat
        twice = next(name for name in names if listed.count(name) > 1)
        raise UsageError(f"--only names {twice!r} twice")
    unknown = [name for name in names if name not in robots]
    if unknown:
        raise UsageError(
            f"--only: no robot {', '.join(map(repr, unknown))} in scenario {scenario!r}; its "
            f"robots: {', '.join(robots)}"
        )
    return names


def _check_across_hosts(args: argparse.Namespace) -> None:
    """`swarm up --connect` joins a world that runs on another host: it needs `--only` and the
    run's credentials, and takes none of the world's settings."""
    if args.connect is None:
        if args.only is not None and args.credentials is None:
            raise UsageError(
                "--only runs a part of the swarm, the rest on other hosts: give the run's "
                "credentials set (`swarm credentials DIR --tls --tls-host HOST`) with "
                "--credentials DIR, and copy DIR to the other hosts"
            )
        return
    if args.listen is not None:
        raise UsageError("--listen is for the world's host, --connect for the others: not both")
    if args.only is None:
        raise UsageError(
            "--connect joins a world that runs on another host: say which robots run here "
            "with --only (e.g. --only robot3,robot4)"
        )
    world_flags = [
        flag
        for flag, given in (
            ("--lockstep", args.lockstep),
            ("--max-speed", args.max_speed is not None),
            ("--duration", args.duration is not None),
            ("--radio", args.radio is not None),
        )
        if given
    ]
    if world_flags:
        raise UsageError(
            f"{', '.join(world_flags)}: the world's settings; give them to `swarm up` on the "
            "world's host (this host runs no world, only the robots of --only)"
        )
    if args.credentials is None:
        raise UsageError(
            "--connect needs the run's credentials: a copy of the world host's set, "
            "--credentials DIR (made there with `swarm credentials DIR --tls --tls-host HOST`)"
        )


def _cmd_up(args: argparse.Namespace) -> int:
    from services.launcher.launcher import Launcher, LaunchError, LaunchPlan, start_problem
    from swarm_config.scenario import load_scenario
    from world.runtime import WorldConfig
    from world.write_failures import EXIT_SUMMARY_NOT_WRITTEN

    endpoint = f"{'tls' if args.tls else 'tcp'}/127.0.0.1:{args.port}"
    # The world's settings, validated here once so that a mistake stops `swarm up` before
    # anything starts; the world process is given exactly these.
    world = _settings(
        WorldConfig,
        {
            "swarm": args.swarm,
            "scenario": args.scenario,
            "connect": [endpoint],
            "lockstep": True if args.lockstep else None,
            "duration_s": args.duration,
            "out_dir": args.out,
            "radio_profile": args.radio,
            "max_speed": args.max_speed,
        },
        None,
        # The run's credentials are made by the launcher, not taken from the environment
        # (which may name the operator's file of another run).
        {k: v for k, v in os.environ.items() if k != CREDENTIALS_FILE_ENV},
    )
    scenario = load_scenario(world.scenario)
    problem = world.scenario_problem(scenario)
    if problem is not None:
        raise UsageError(problem)
    only = _only_robots(args.only, scenario.name, scenario.robot_names)
    _check_across_hosts(args)
    out_dir = Path(args.out)  # made by the launcher once the plan passes its checks
    plan = LaunchPlan(
        scenario=world.scenario,
        robots=scenario.robot_names,
        out_dir=out_dir,
        swarm=world.swarm,
        endpoint=endpoint,
        lockstep=world.lockstep,
        max_speed=world.max_speed,
        duration_s=world.duration_s,
        radio_profile=world.radio_profile,
        dashboard=not args.no_dashboard,
        web_port=args.web_port,
        grpc_port=args.grpc_port,
        credentials_dir=Path(args.credentials) if args.credentials else None,
        only=only,
        link_listen=split_endpoints(args.listen) if args.listen else (),
        link_connect=split_endpoints(args.connect) if args.connect else (),
    )
    try:
        plan.check()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    problem = start_problem(plan)  # before the run folder is touched
    if problem is not None:
        print(f"swarm up: {problem}", file=sys.stderr)
        return 1
    try:
        launcher = Launcher(plan)
    except (CredentialsError, TlsError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    _install_stop(launcher.stop)

    def ready() -> None:
        mode = "lockstep" if plan.lockstep else "real time"
        length = f"{plan.duration_s} s" if plan.duration_s else "until Ctrl-C"
        elsewhere = [name for name in scenario.robot_names if name not in plan.started_robots]
        if not plan.runs_world:
            print(
                f"swarm {plan.swarm}: {', '.join(plan.started_robots)} on {endpoint}, this "
                f"host's router linked to the world's at {', '.join(plan.link_connect)} "
                "(until Ctrl-C)",
                flush=True,
            )
        else:
            print(
                f"swarm {plan.swarm}: {', '.join(plan.started_robots)} on {endpoint} "
                f"({mode}, {length})",
                flush=True,
            )
        if plan.link_listen:
            print(
                f"other hosts' routers: --connect {', '.join(plan.link_listen)}"
                + (f" (expected there: {', '.join(elsewhere)})" if elsewhere else ""),
                flush=True,
            )
        summary = f"; summary: {out_dir / 'summary.json'}" if plan.runs_world else ""
        print(f"logs: {out_dir / 'logs'}/<process>.log{summary}", flush=True)
        made = "the run's, on every host" if plan.across_hosts else "new for this run"
        print(
            f"credentials: {launcher.credentials_dir}/<identity>.json ({made}; the "
            f"swarm command line uses {launcher.credentials_dir}/{OPERATOR}.json)",
            flush=True,
        )
        if launcher.tls is not None and endpoint.startswith("tls/"):
            print(
                f"TLS: the router's certificate is signed by {launcher.tls.ca_certificate}; "
                f"the swarm command line needs ${TLS_ROOT_CA_ENV}=<that path> and "
                f"--connect {endpoint}",
                flush=True,
            )
        if "dashboard" in launcher.children:
            print(
                f"dashboard: open {plan.viewer_url}  (recording: {out_dir / 'dashboard.rrd'})",
                flush=True,
            )
        robot = plan.started_robots[-1] if plan.started_robots else "robot2"
        print(
            f"try: swarm status | swarm fault kill {robot} | swarm fault restart {robot} | "
            f"swarm fault partition {robot} | swarm fault heal",
            flush=True,
        )

    started_s = time.monotonic()
    try:
        code = launcher.up(on_ready=ready)
    except LaunchError as exc:
        print(f"swarm up: {exc}", file=sys.stderr)
        return 1
    wall_s = time.monotonic() - started_s
    if not plan.runs_world:
        print(f"stopped {', '.join(plan.started_robots)} after {wall_s:.1f} s of wall time")
        return code
    summary_path = out_dir / "summary.json"
    final_lost = launcher.world_exit_code == EXIT_SUMMARY_NOT_WRITTEN
    if final_lost:
        print(
            f"swarm up: the world could not write the run's final {summary_path} (is the disk "
            "full, or the folder read-only?)",
            file=sys.stderr,
        )
        code = EXIT_WRITE_FAILED
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        print(f"no readable {summary_path}: see {out_dir / 'logs'}/world.log", file=sys.stderr)
        return code or 1
    if final_lost:
        print(
            f"what follows is from the last summary it wrote, at t = {summary['duration_s']:.1f} s",
            file=sys.stderr,
        )
    factor = summary.get("real_time_factor")
    if factor is None:  # lockstep: the speed-up over real time, start-up included
        factor = summary["duration_s"] / max(wall_s, 1e-9)
    print(
        f"ran {summary['duration_s']:.1f} simulated s in {wall_s:.1f} s of wall time "
        f"({summary['clock_mode'].replace('_', ' ')}; real-time factor {factor:.2f})"
    )
    _print_headline(summary)
    guard = summary.get("starvation_guard") or {}
    if guard.get("enabled") and guard.get("holds"):
        passed_over = {name: n for name, n in guard["lapses"].items() if n}
        behind_s = guard.get("world_behind_s") or 0.0
        world_part = f", {behind_s:.1f} s of it for the world's own lag" if behind_s else ""
        print(
            f"  starvation guard: time held {guard['held_s']:.1f} s in {guard['holds']} holds "
            f"for late robots{world_part} (longest {1000 * guard['longest_hold_s']:.0f} ms); "
            f"passed over: {passed_over or 'none'}"
        )
    if summary["clock_mode"] == "real_time":
        _print_real_time_verdict(summary)
    if not final_lost:
        print(f"wrote {summary_path}")
    return code


def _print_real_time_verdict(summary: dict[str, Any]) -> None:
    """Each robot's missed deadlines, and whether the run held real time (the criterion of
    bench/scale.py, services/real_time_hold.py), with what to do when it did not."""
    deadlines: dict[str, tuple[int, int]] = {}
    for name, timing in (summary.get("control_timing") or {}).items():
        if timing:
            deadlines[name] = (timing["deadline_misses"], timing["ticks"])
            print(
                f"  {name:<7} {timing['deadline_misses']} of {timing['ticks']} control "
                "deadlines missed"
            )
    shortfalls = real_time_shortfalls(summary.get("real_time_factor"), deadlines)
    if shortfalls:
        print(
            f"  did not hold real time: {'; '.join(shortfalls)}. On a host short of CPU run "
            "fewer robots, or --lockstep, which waits for every robot (docs/scale.md)"
        )


def _print_headline(s: dict[str, object]) -> None:
    """The run's headline figures from its summary.json (docs/summary-schema.md)."""
    print(
        f"  leader tracking RMS   {_cm(s['leader_tracking_rms_m'])}  (nominal samples, t >= "
        f"{s['steady_state_start_s']} s)"
    )
    formation = s["formation_rms_m"]
    assert isinstance(formation, dict)
    for name, value in formation.items():
        print(f"  formation RMS {name:<7} {_cm(value)}")
    print(
        f"  min obstacle clearance {_cm(s['min_obstacle_clearance_m'])}, "
        f"min robot separation {_cm(s['min_robot_separation_m'])}, collisions {s['collisions']}"
    )


def _ask(args: argparse.Namespace, target: str, verb: str, body: BaseModel | bytes | None) -> bytes:
    payload = _ask_if_answered(args, target, verb, body)
    if payload is None:
        raise _no_answer(args, target)
    return payload


def _no_answer(args: argparse.Namespace, target: str) -> UsageError:
    """The error for a process that gave no answer, saying why when the launcher knows (it is
    down, stopped or exited), else suggesting that no swarm runs there."""
    where = f"no answer from {target} of swarm {_swarm(args)!r} at {_endpoints(args.connect)[0]}"
    why = None if target == "launcher" else _why_no_answer(args, target)
    why = why or _why_launcher_silent(args)
    return UsageError(f"{where} ({why or 'is it running? start one with `swarm up`'})")


def _why_launcher_silent(args: argparse.Namespace) -> str | None:
    """What this host knows of a launcher that did not answer: the `swarm up` whose
    credentials this command uses holds their folder's lock (services/launcher/run_lock.py),
    which names its process.  None when no such process runs here."""
    from services.launcher.process_state import STOPPED_STATES, process_state
    from services.launcher.run_lock import recorded_holder

    source = args.credentials or os.environ.get(CREDENTIALS_FILE_ENV)
    pid = recorded_holder((Path(source) if source else DEFAULT_OPERATOR_CREDENTIALS).parent)
    if pid is None:
        return None
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    if b"up" not in cmdline:  # the pid of a launcher long gone, now another process's
        return None
    if process_state(pid) in STOPPED_STATES:
        return f"the launcher of this run (pid {pid}) is stopped: `kill -CONT {pid}` continues it"
    return f"the launcher of this run (pid {pid}) runs but did not answer in time"


LAUNCHER_ASKED_WHY_TIMEOUT_S = 1.0
"""How long a command that got no answer from a process asks the launcher about it."""


def _why_no_answer(args: argparse.Namespace, target: str) -> str | None:
    """What the launcher's status says of `target`, when it answers and knows it: down until
    restarted, stopped, exited by itself, running yet silent, or not among its processes.
    None when no launcher answers (under compose)."""
    from robot_firmware.net.messages import LauncherStatusReply, parse_reply

    quick = argparse.Namespace(
        **{**vars(args), "timeout": min(args.timeout, LAUNCHER_ASKED_WHY_TIMEOUT_S)}
    )
    payload = _ask_if_answered(quick, "launcher", "status", None)
    status = None if payload is None else parse_reply(LauncherStatusReply, payload)
    if not isinstance(status, LauncherStatusReply):
        return None
    if target not in status.processes:  # a typo, or one run by another host's launcher
        return f"the launcher that answered runs no {target!r}: {', '.join(status.processes)}"
    process = status.processes[target]
    if process.stopped:
        return f"it is stopped: `swarm fault cont {target}` continues it"
    if process.killed and not process.running:
        return f"it was killed and stays down: `swarm restart {target}` starts it again"
    if not process.running:
        return (
            f"it exited by itself (status {process.exit_code}): see {process.log}; "
            f"`swarm restart {target}` starts it again"
        )
    return f"it runs (pid {process.pid}) but did not answer in time; see {process.log}"


def _ask_if_answered(
    args: argparse.Namespace,
    target: str,
    verb: str,
    body: BaseModel | bytes | None,
    router_may_be_down: bool = False,
) -> bytes | None:
    """The reply's payload, or None when nobody answered within --timeout (or, when
    `router_may_be_down`, no router let this command in: it is restarting)."""
    from robot_firmware.net.admin import CONNECT_TIMEOUT_S, RouterUnreachableError, ask

    try:
        check_name("process", target)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    problem = _target_problem(target, verb)
    if problem is not None:
        raise UsageError(problem)
    swarm = _swarm(args)
    endpoint = _endpoints(args.connect)[0]
    credentials = _operator_credentials(args.credentials)
    try:
        return ask(swarm, endpoint, target, verb, body, args.timeout, credentials)
    except RouterUnreachableError:
        if router_may_be_down:
            return None
        raise UsageError(
            f"no router at {endpoint} let the {credentials.identity} in within "
            f"{CONNECT_TIMEOUT_S:g} s: "
            "no swarm runs there (start one with `swarm up`), it is another run's "
            "(give that run's operator credentials with --credentials), or its router is "
            "stopped (`swarm fault stop router`: continue it with `kill -CONT` and its pid)"
        ) from None


ANSWERS_NO_ADMIN = {
    ROUTER: "the router answers no admin requests; `swarm status` shows it (pid, restarts, "
    "log) and `swarm kill|restart router` act on it",
    DASHBOARD: "the dashboard answers no admin requests; `swarm status` shows it (pid, "
    "restarts, log) and `swarm kill|restart dashboard` act on it",
    OPERATOR: "operator is the identity of this command line, not a process of the swarm",
}
"""What to say of a swarm process that serves no admin verb (only robots, the world and the
launcher do), instead of waiting for an answer that cannot come."""
ROBOT_VERBS = ("regs", "params")
"""Admin verbs only a robot serves."""


def _target_problem(target: str, verb: str) -> str | None:
    """Why `target` cannot answer `verb`, when the command line knows it without asking: a
    service process without admin verbs, or a robot's verb sent to a service (no robot may
    take a service's name: swarm_config/credentials.py)."""
    if target in ANSWERS_NO_ADMIN:
        return ANSWERS_NO_ADMIN[target]
    if verb in ROBOT_VERBS and target in SERVICE_IDENTITIES:
        return f"{target} is not a robot: only a robot answers `{verb}` (e.g. robot1)"
    return None


def _print_reply(payload: bytes) -> int:
    """Print an admin reply as indented JSON; exit status 1 when it is a refusal."""
    from robot_firmware.net.admin import reply_as_json

    reply = reply_as_json(payload)
    if reply is None:
        raise UsageError(f"the answer is not a JSON object: {payload[:200]!r}")
    print(json.dumps(reply, indent=2))
    return 0 if reply.get("ok") is True else 1


WORLD_STATUS_TIMEOUT_S = 1.0
"""How long `swarm status` waits for the world's line after the launcher's reply."""


def _cmd_status(args: argparse.Namespace) -> int:
    """The launcher's processes and the world's line; with a process, its own status."""
    if args.process is not None:
        return _print_reply(_ask(args, args.process, "status", None))
    code = _print_reply(_ask(args, "launcher", "status", None))
    _print_world_line(args)
    return code


def _print_world_line(args: argparse.Namespace) -> None:
    """One line on stderr (stdout stays the launcher's JSON): the world's simulation time,
    clock mode and real-time factor, which drops below 1 while the world holds its time for
    a starved robot (world/realtime_guard.py), and what it refused from the robots
    (malformed or spoofed input, floods over the input budgets: world/input_budget.py)."""
    from robot_firmware.net.messages import WorldStatusReply, parse_reply

    quick = argparse.Namespace(
        **{**vars(args), "timeout": min(args.timeout, WORLD_STATUS_TIMEOUT_S)}
    )
    payload = _ask_if_answered(quick, "world", "status", None, True)
    reply = None if payload is None else parse_reply(WorldStatusReply, payload)
    if not isinstance(reply, WorldStatusReply):
        print(f"world: no answer within {quick.timeout:g} s", file=sys.stderr)
        return
    factor = "n/a" if reply.real_time_factor is None else f"{reply.real_time_factor:.2f}"
    print(
        f"world: t = {reply.t_s:.1f} s, {reply.clock_mode.replace('_', ' ')}, real-time factor "
        f"{factor} since start, {len(reply.live)} of {len(reply.robots)} robots live; "
        f"refused from robots: {reply.refused_input.describe()}",
        file=sys.stderr,
    )
    if reply.write_failures:
        failed = ", ".join(f"{what} {n}" for what, n in reply.write_failures.items())
        print(
            f"world: writes of the run folder failed (is its disk full?): {failed}",
            file=sys.stderr,
        )


def _cmd_kill(args: argparse.Namespace) -> int:
    return _ask_launcher_to(args, "kill", args.process)


def _cmd_restart(args: argparse.Namespace) -> int:
    return _ask_launcher_to(args, "restart", args.process)


def _ask_launcher_to(args: argparse.Namespace, verb: str, process: str) -> int:
    """Ask the launcher to `verb` (kill, restart) `process` and print its answer.  The answer
    to one on the router goes down with the router it kills: then the launcher's status is
    shown once it answers again, through the router it started anew."""
    from robot_firmware.net.messages import ProcessRequest

    request = ProcessRequest(process=process)
    if process != "router":
        return _print_reply(_ask(args, "launcher", verb, request))
    payload = _ask_if_answered(args, "launcher", verb, request)
    if payload is None:
        return _print_launcher_status_after_router(args, verb)
    return _print_reply(payload)


def _print_launcher_status_after_router(args: argparse.Namespace, verb: str) -> int:
    """No answer came after `verb router`, as none can: say so, then print the launcher's
    status once it has reconnected to the router it started again."""
    print(
        f"swarm {args.command}: no answer through the router after `{verb} router` (the "
        "answer went down with it); the launcher's status:",
        file=sys.stderr,
    )
    deadline_s = time.monotonic() + ROUTER_BACK_WITHIN_S
    while (status := _ask_if_answered(args, "launcher", "status", None, True)) is None:
        if time.monotonic() > deadline_s:
            raise _no_answer(args, "launcher")
        time.sleep(0.5)
    return _print_reply(status)


def _cmd_fault(args: argparse.Namespace) -> int:
    """Send one fault to the world's `fault` verb, the entry point of every fault: the world
    applies it at a tick boundary and records it.  A world that does not answer its `status`
    (it is down or frozen) cannot: a process fault then goes to the launcher directly, with no
    world to record it.  A fault the world takes on itself (kill, stop, restart of `world`) is
    recorded before the world goes, and the answer to one on the router goes down with it: for
    those, no answer is what success looks like, and the launcher's status is shown instead."""
    from robot_firmware.net.messages import ProcessRequest
    from services.cli.faults import FaultArgumentError, fault_from_args, fault_json
    from swarm_config.faults import fault_subjects

    try:
        fault = fault_from_args(args)
    except FaultArgumentError as exc:
        raise UsageError(str(exc)) from None
    body = fault_json(fault)
    if args.dry_run:
        print(body.decode())
        return 0
    stops_router = fault.kind == "process" and fault.fault == "stop"
    stops_router = stops_router and fault_subjects(fault)[0] == "router"
    router_pid = _router_pid(args) if stops_router else None
    # Every command passes the router, `swarm fault cont router` too: only a signal from this
    # host continues a stopped one.
    how_to_continue = (
        "swarm fault: the router is stopped, so no command reaches the swarm until it "
        f"continues: `kill -CONT {router_pid or '<its pid>'}`"
    )
    if _ask_if_answered(args, "world", "status", None) is None:
        if fault.kind != "process":
            raise _no_answer(args, "world")
        process = fault_subjects(fault)[0]
        print(
            f"swarm fault: the world does not answer (down or frozen); asking the launcher to "
            f"{fault.fault} {process} directly (no world records it in events.jsonl)",
            file=sys.stderr,
        )
        if stops_router:  # its answer cannot pass the router it stopped
            _ask_if_answered(args, "launcher", fault.fault, ProcessRequest(process=process))
            print(how_to_continue, file=sys.stderr)
            return 0
        return _ask_launcher_to(args, fault.fault, process)
    payload = _ask_if_answered(args, "world", "fault", body)
    if stops_router:
        print(how_to_continue, file=sys.stderr)
    if payload is None and fault.kind == "process" and fault_subjects(fault)[0] == "world":
        print(
            f"swarm fault: the world took `{fault.fault}` on itself and gave no answer (it "
            "recorded the fault first); the launcher's status:",
            file=sys.stderr,
        )
        return _print_reply(_ask(args, "launcher", "status", None))
    if payload is None and fault.kind == "process" and fault_subjects(fault)[0] == "router":
        return _print_launcher_status_after_router(args, fault.fault)
    if payload is None:
        raise _no_answer(args, "world")
    return _print_reply(payload)


def _router_pid(args: argparse.Namespace) -> int | None:
    """The router's process id from the launcher's status, or None (no launcher answers, as
    under compose, or it names none)."""
    from robot_firmware.net.messages import LauncherStatusReply, parse_reply

    payload = _ask_if_answered(args, "launcher", "status", None)
    status = None if payload is None else parse_reply(LauncherStatusReply, payload)
    if not isinstance(status, LauncherStatusReply) or "router" not in status.processes:
        return None
    return status.processes["router"].pid


NET_FIELD_FLAGS = (("latency_ms", "--latency-ms"), ("jitter_ms", "--jitter-ms"), ("loss", "--loss"))
"""The fields of the running link profile `swarm net set` changes, and their flags."""


def _cmd_net(args: argparse.Namespace) -> int:
    """`net get`, or `net set` of a named profile or of some fields of the running one; a
    combination the world would not apply as given is refused before anything is sent."""
    fields = {key: getattr(args, key) for key, _ in NET_FIELD_FLAGS}
    given = [flag for key, flag in NET_FIELD_FLAGS if fields[key] is not None]
    body: bytes | None = None
    if args.action == "get":
        if args.profile is not None or given:
            flags = ["--profile"] * (args.profile is not None) + given
            raise UsageError(
                f"net get takes no {', '.join(flags)}: `swarm net set` changes the profile"
            )
    elif args.profile is not None:
        if given:
            raise UsageError(
                f"give either --profile or {', '.join(given)}, not both: `net set --profile "
                f"{args.profile}` then `net set {given[0]} X` gives that profile with its field "
                "changed"
            )
        body = json.dumps({"profile": args.profile}).encode()
    elif given:
        body = json.dumps({k: v for k, v in fields.items() if v is not None}).encode()
    else:
        raise UsageError("give --profile or at least one of --latency-ms, --jitter-ms, --loss")
    return _print_reply(_ask(args, "world", "net", body))


def _cmd_regs(args: argparse.Namespace) -> int:
    from robot_firmware.net.messages import (
        AdminError,
        RegsAccessReply,
        RegsDumpReply,
        RegsRequest,
        parse_reply,
    )

    if args.address is None:
        request = RegsRequest(op="dump")
    elif args.value is None:
        request = RegsRequest(op="read", address=args.address)
    else:
        request = RegsRequest(op="write", address=args.address, value=args.value)
    payload = _ask(args, args.robot, "regs", request)
    reply: RegsDumpReply | RegsAccessReply | AdminError | None
    if request.op == "dump":
        reply = parse_reply(RegsDumpReply, payload)
    else:
        reply = parse_reply(RegsAccessReply, payload)
    if reply is None:
        raise UsageError(f"{args.robot} answered something that is not a regs reply")
    if isinstance(reply, AdminError):
        print(f"swarm regs: {reply.error}", file=sys.stderr)
        return 1
    if isinstance(reply, RegsDumpReply):
        for row in reply.registers:
            print(
                f"0x{row.address:08X}  {row.peripheral + '.' + row.name:<28} "
                f"{row.access:<4} 0x{row.value:08X}"
            )
    else:
        print(f"0x{reply.address:08X}  {reply.name}  0x{reply.value:08X}")
    return 0


PARAMS_FILE_BYTES_MAX = 64 << 10
"""The largest fuzzy parameter file `swarm params` sends: such a file is a few hundred bytes,
and the router refuses any message over 1 MiB (services/router/access.py)."""


def _cmd_params(args: argparse.Namespace) -> int:
    body: bytes | None = None
    if args.file is not None:
        try:
            body = read_input_file(Path(args.file), "fuzzy parameter file", PARAMS_FILE_BYTES_MAX)
        except SettingsError as exc:
            raise UsageError(str(exc)) from None
        if _holds_no_yaml(body):  # sent, it would be the robot's "show them" request
            raise UsageError(
                f"{args.file}: fuzzy parameter file is empty (only blanks or comments): "
                "nothing sent; without FILE `swarm params` shows the robot's parameters"
            )
    return _print_reply(_ask(args, args.robot, "params", body))


def _holds_no_yaml(data: bytes) -> bool:
    """Whether a YAML file is empty to its parser: nothing, or only blank and comment lines
    (a line whose first non-blank character is # is a comment wherever it stands)."""
    lines = data.removeprefix(b"\xef\xbb\xbf").splitlines()
    return all(not line.strip() or line.lstrip().startswith(b"#") for line in lines)


ADMIN_TIMEOUT_MAX_S = 86_400.0
"""The longest --timeout of a command that asks the swarm: one day.  Zenoh takes no time-out
past about 1e19 s (`ValueError: negative timeout`, a traceback), and no answer is worth more."""


def _admin_timeout(text: str) -> float:
    """--timeout of the commands that ask a running swarm, for argparse's `type=`: seconds
    above 0 and at most `ADMIN_TIMEOUT_MAX_S`."""
    seconds = positive_seconds(text)
    if seconds > ADMIN_TIMEOUT_MAX_S:
        raise argparse.ArgumentTypeError(
            f"{text!r} is more than one day: give at most {ADMIN_TIMEOUT_MAX_S:,.0f} seconds"
        )
    return seconds


BUS_WORD_MAX = 0xFFFF_FFFF
"""The largest address and word of the robots' 32-bit register bus."""


BUS_WORD_FORMS = (
    "decimal digits without a leading 0 (e.g. 4096) or 0x and hex digits (e.g. 0xFF200000)"
)
"""The forms an address or value of `swarm regs` takes, for its messages."""
_BUS_WORD = re.compile(r"0|[1-9][0-9]*|0[xX][0-9A-Fa-f]+")
"""Those forms, ASCII only: no sign, space, `_`, 0b/0o, leading 0 (octal to devmem and C)
or other digits, all of which Python's `int(text, 0)` took."""


def _bus_word(text: str) -> int:
    """An address or a value of one 32-bit bus access: `BUS_WORD_FORMS`."""
    shown = repr(text) if len(text) <= 40 else f"{text[:32]!r}... ({len(text)} characters)"
    digits = text.removeprefix("-")
    if not _BUS_WORD.fullmatch(digits) or (digits != text and _word(digits) == 0):
        raise argparse.ArgumentTypeError(
            f"{shown} is not an integer of the accepted forms: {BUS_WORD_FORMS}"
        )
    if digits != text or _word(digits) > BUS_WORD_MAX:
        raise argparse.ArgumentTypeError(
            f"{shown} does not fit the 32-bit bus (0x0 to 0x{BUS_WORD_MAX:X})"
        )
    return _word(digits)


def _word(digits: str) -> int:
    """The number of a `_BUS_WORD` match; a decimal too long to fit 32 bits is counted as
    one past them (Python refuses to convert one of over 4,300 digits)."""
    if digits[1:2] in ("x", "X"):
        return int(digits, 16)
    return int(digits) if len(digits) <= len(str(BUS_WORD_MAX)) else BUS_WORD_MAX + 1


def _process_name(text: str) -> str:
    """A process of `swarm kill` and `swarm restart`, for argparse's `type=`: a name that
    could be one (`''` and `a/b` were sent to the launcher, which answered with its list)."""
    try:
        return check_name("process", text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _endpoints(given: str | None) -> list[str]:
    if given:
        return split_endpoints(given)
    from_environment = os.environ.get("ZENOH_CONNECT", "")
    if not from_environment.strip():
        return [DEFAULT_ENDPOINT]
    try:
        return split_endpoints(endpoint_list(from_environment))
    except argparse.ArgumentTypeError as exc:
        raise UsageError(f"$ZENOH_CONNECT: {exc}") from None


def _operator_credentials(given: str | None) -> ProcessCredentials:
    """The credentials the command line talks to a swarm with: --credentials FILE, else
    $SWARM_CREDENTIALS_FILE, else runs/swarm/credentials/operator.json when it exists."""
    source = given or os.environ.get(CREDENTIALS_FILE_ENV)
    if not source and DEFAULT_OPERATOR_CREDENTIALS.exists():
        source = str(DEFAULT_OPERATOR_CREDENTIALS)
    if not source:
        raise UsageError(f"no operator credentials: {HOW_TO_GET_CREDENTIALS}")
    try:
        return read_credentials(Path(source))
    except CredentialsError as exc:
        raise UsageError(str(exc)) from None


def _swarm(args: argparse.Namespace) -> str:
    """The swarm name of --swarm, else $SWARM_NAME, else lab; UsageError naming where a name
    that cannot be a key chunk came from."""
    # A given --swarm is checked as given: '' (an unset variable, `--swarm "$SWARM"`) was lab.
    source = "--swarm" if args.swarm is not None else "$SWARM_NAME"
    swarm: str = args.swarm if args.swarm is not None else os.environ.get("SWARM_NAME") or "lab"
    try:
        return check_name("swarm", swarm)
    except ValueError as exc:
        raise UsageError(f"{source}: {exc}") from None


def _cm(value: object) -> str:
    if value is None:
        return "n/a"
    return f"{100.0 * float(value):.2f} cm"  # type: ignore[arg-type]


def _db(value: object) -> str:
    if value is None:
        return "n/a"
    return f"{float(value):.6f} dB"  # type: ignore[arg-type]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The `swarm` parser.  Given the `command` about to run, and if it is one of the light
    ones (those defined here and `fault`), it leaves out the subcommands whose modules cost
    seconds to load (the tuner pulls in the batch simulator, the world and numba; the dashboard
    and the scenario generator the scenario models and the control kernels), so that a robot
    process or a `swarm status` starts at once.  `swarm`, `swarm --help` and an unknown command
    get the whole parser."""
    parser = argparse.ArgumentParser(
        prog="swarm",
        description=(
            "Emulator of a swarm robotic cyber-physical system: leader-follower formation with "
            "fuzzy-scheduled PID, APF obstacle avoidance and OFA tuning."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sim = sub.add_parser(
        "sim",
        help="run a scenario in the in-process batch simulator",
        description=(
            "Run one scenario file in the batch simulator and write DIR/summary.json and the "
            "paper's Figs. 11-13 as PNG. The scenario's controller is run side by side with its "
            "counterpart (fixed-gain vs fuzzy-scheduled PID) under the same noise, and both are "
            "reported. Equal seeds give byte-identical summary.json files."
        ),
    )
    sim.add_argument("--scenario", required=True, metavar="FILE", help="scenario YAML file")
    sim.add_argument("--out", required=True, metavar="DIR", help="output directory")
    sim.add_argument("--seed", type=int, help="override the scenario's seed")
    sim.add_argument("--duration", type=float, metavar="S", help="override duration_s")
    sim.add_argument(
        "--no-compare", action="store_true", help="run only the scenario's own controller"
    )
    sim.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    sim.set_defaults(handler=_cmd_sim)

    def swarm_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--swarm",
            help="swarm name, the first chunk of every key (default: $SWARM_NAME, else lab)",
        )
        p.add_argument(
            "--connect",
            type=endpoint_list,
            metavar="ENDPOINTS",
            help=f"router endpoint(s), comma separated (default: {DEFAULT_ENDPOINT}, "
            "$ZENOH_CONNECT)",
        )

    def credentials_option(p: argparse.ArgumentParser, default: str) -> None:
        p.add_argument(
            "--credentials",
            metavar="FILE",
            help=f"credentials file (default: ${CREDENTIALS_FILE_ENV}{default}); `swarm up` "
            f"writes one per process to DIR/{CREDENTIALS_DIR_NAME}/",
        )

    def admin_query_options(p: argparse.ArgumentParser, suppress_defaults: bool = False) -> None:
        """suppress_defaults: for a subcommand's copy of options its parent has too, so that
        one given before the subcommand is not reset by the subcommand's default."""
        swarm_options(p)
        credentials_option(p, f", else {DEFAULT_OPERATOR_CREDENTIALS} when it exists")
        p.add_argument(
            "--timeout",
            type=_admin_timeout,
            default=3.0,
            metavar="S",
            help="seconds to wait for the answer, above 0 and at most "
            f"{ADMIN_TIMEOUT_MAX_S:,.0f} (one day; default: 3)",
        )
        if suppress_defaults:
            for action in p._actions:
                if action.dest in ("swarm", "connect", "credentials", "timeout"):
                    action.default = argparse.SUPPRESS

    up = sub.add_parser(
        "up",
        help="start router, world and one process per robot, and supervise them",
        description=(
            "Start the swarm locally without Docker: a Zenoh router, the world process and one "
            "process per robot of the scenario, each logging to DIR/logs. Stops everything on "
            "Ctrl-C or after --duration and leaves DIR/summary.json. While it runs, "
            "`swarm status`, `swarm fault ...` (process, network and register faults, recorded "
            "in DIR/events.jsonl), `swarm kill ROBOT`, `swarm restart ROBOT`, `swarm net set` "
            "and `swarm regs ROBOT` act on it. A scenario's faults: schedule is a campaign "
            "(configs/campaigns/)."
        ),
    )
    up.add_argument(
        "--scenario",
        metavar="FILE",
        help=f"scenario YAML (default: $SWARM_SCENARIO, else {DEFAULT_SCENARIO})",
    )
    up.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="simulated seconds to run (default: until Ctrl-C)",
    )
    up.add_argument(
        "--lockstep",
        action="store_true",
        help="the world waits for every live robot each tick (deterministic)",
    )
    up.add_argument("--max-speed", type=float, metavar="X", help=MAX_SPEED_HELP)
    up.add_argument("--no-dashboard", action="store_true", help="do not start the dashboard")
    up.add_argument(
        "--web-port", type=tcp_port, default=9090, help="dashboard web viewer port (default: 9090)"
    )
    up.add_argument(
        "--grpc-port", type=tcp_port, default=9876, help="dashboard gRPC data port (default: 9876)"
    )
    up.add_argument(
        "--out",
        default="runs/swarm",
        metavar="DIR",
        help="run directory for logs and summary.json (default: runs/swarm)",
    )
    up.add_argument("--radio", metavar="PROFILE", help="radio profile to start with")
    up.add_argument(
        "--swarm", help="swarm name, the first chunk of every key (default: $SWARM_NAME, else lab)"
    )
    up.add_argument("--port", type=tcp_port, default=7447, help="router TCP port on 127.0.0.1")
    up.add_argument(
        "--tls",
        action="store_true",
        help="links over TLS (tls/127.0.0.1:PORT) with the run's own CA in "
        f"<credentials>/{TLS_DIR_NAME}/ (one there from `swarm credentials --tls` is used)",
    )
    up.add_argument(
        "--credentials",
        metavar="DIR",
        help=f"use the credentials in DIR (written by an earlier run or by `swarm credentials`; "
        f"a new run id is written into them, but not with --only, --listen or --connect: "
        f"the hosts of one run share its run id) instead of a fresh set in "
        f"DIR/{CREDENTIALS_DIR_NAME}/",
    )
    up.add_argument(
        "--only",
        metavar="ROBOTS",
        help="start only these robots of the scenario (comma separated, e.g. robot3,robot4); "
        "the others run on other hosts (docs/multi-host.md); needs --credentials",
    )
    up.add_argument(
        "--listen",
        type=endpoint_list,
        metavar="ENDPOINT",
        help="the world's host: where its router also takes the other hosts' routers, "
        "tls/ADDRESS:PORT (an address its router certificate names; docs/multi-host.md)",
    )
    up.add_argument(
        "--connect",
        type=endpoint_list,
        metavar="ENDPOINT",
        help="join a world that runs on another host: link this host's router to that host's "
        "--listen endpoint (tls/HOST:PORT) and start only the robots of --only, no world",
    )
    up.set_defaults(handler=_cmd_up)

    creds = sub.add_parser(
        "credentials",
        help="write the credentials of a swarm's processes (and its router config) into DIR",
        description=(
            "One file per identity (router, world, launcher, dashboard, operator and every "
            "robot of the scenario), mode 0600 in a 0700 directory, the router's user file and "
            "its config with the access control of the run. A complete set already in DIR "
            "keeps its secrets (only the run id is new) unless --rotate is given. `swarm up` "
            "makes a fresh set by itself; this is for containers and your own deployments."
        ),
    )
    creds.add_argument("dir", metavar="DIR", help="the credentials directory")
    creds.add_argument("--scenario", metavar="FILE", help="scenario YAML (its robots)")
    creds.add_argument("--swarm", help="swarm name (default: $SWARM_NAME, else lab)")
    creds.add_argument("--rotate", action="store_true", help="new secrets even if DIR has some")
    creds.add_argument(
        "--listen",
        action="append",
        type=endpoint_list,
        metavar="ENDPOINT",
        help=f"the router config's listen endpoint (repeatable; default {DEFAULT_ENDPOINT}, "
        f"with --tls {DEFAULT_TLS_ENDPOINT})",
    )
    creds.add_argument(
        "--tls",
        action="store_true",
        help=f"also a CA and the router's TLS certificate in DIR/{TLS_DIR_NAME}/ (kept if "
        "there, unless --rotate), named in the router config",
    )
    creds.add_argument(
        "--tls-host",
        action="append",
        metavar="HOST",
        help="a host name or IP address clients reach the router at, for its certificate "
        f"(repeatable; default {' and '.join(DEFAULT_TLS_HOSTS)})",
    )
    creds.set_defaults(handler=_cmd_credentials)

    for name, text, handler in (
        ("status", "show the processes of a running swarm", _cmd_status),
        ("kill", "SIGKILL a process of a running swarm (a power cut)", _cmd_kill),
        ("restart", "start a process of a running swarm again", _cmd_restart),
    ):
        cmd = sub.add_parser(name, help=text, description=text + ".")
        if name != "status":
            cmd.add_argument(
                "process",
                type=_process_name,
                help="a robot's name (e.g. robot2), world, router or dashboard",
            )
        else:
            cmd.add_argument(
                "process",
                nargs="?",
                help="a robot's name (e.g. robot2) or world: that process's own status as "
                "JSON instead (a robot's: its telemetry now, deadline misses and jitter, "
                "safe stops, frames taken and refused, the register model it runs)",
            )
        admin_query_options(cmd)
        cmd.set_defaults(handler=handler)

    net = sub.add_parser(
        "net",
        help="show or change the radio medium's link profile while the swarm runs",
        description=(
            "`swarm net get` prints the running link profile; `swarm net set` changes it: "
            "either --profile NAME (ideal, lab, lossy, bursty) switches to a named profile, or "
            "any of --latency-ms, --jitter-ms, --loss change those fields of the running one, "
            "not both (`net set --profile NAME` then `net set --loss X` gives the named profile "
            "with its loss changed). An invalid request is refused and the running profile "
            "stays."
        ),
    )
    net.add_argument("action", choices=["get", "set"])
    net.add_argument("--profile", metavar="NAME", help="switch to a named profile")
    net.add_argument("--latency-ms", type=float, metavar="MS", help="mean one-way delay, ms")
    net.add_argument(
        "--jitter-ms", type=float, metavar="MS", help="delay spread: uniform in mean +- this, ms"
    )
    net.add_argument("--loss", type=float, help="loss probability, 0..1")
    admin_query_options(net)
    net.set_defaults(handler=_cmd_net)

    regs = sub.add_parser(
        "regs",
        help="read or write a live robot's FPGA registers (like devmem)",
        description=(
            "With only ROBOT, dump every register by name (stored bits, no side effects). With "
            "ADDR, do one bus read; with ADDR and VALUE, one bus write. Addresses and values "
            f"are {BUS_WORD_FORMS}, up to 0x{BUS_WORD_MAX:X}; nothing else (no sign, "
            "spaces, _, 0b or 0o). A refused access is reported as the bus error "
            "it is."
        ),
    )
    regs.add_argument("robot")
    regs.add_argument("address", nargs="?", type=_bus_word, metavar="ADDR")
    regs.add_argument("value", nargs="?", type=_bus_word, metavar="VALUE")
    admin_query_options(regs)
    regs.set_defaults(handler=_cmd_regs)

    params = sub.add_parser(
        "params",
        help="show or replace a live robot's fuzzy scheduler parameters",
        description=(
            "Without FILE, print the robot's fuzzy parameters. With FILE (a fuzzy parameter "
            "file, e.g. the best_fuzzy.yaml of `swarm tune`), send it to the robot: it is "
            "validated and applied between control ticks; a bad file is refused with the "
            "reason and the old parameters stay."
        ),
    )
    params.add_argument("robot")
    params.add_argument("file", nargs="?", metavar="FILE")
    admin_query_options(params)
    params.set_defaults(handler=_cmd_params)

    world = sub.add_parser(
        "world",
        help="run the world process (physics, sensors, radio medium)",
        description="The world process of a swarm; `swarm up` starts it for you.",
    )
    world.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file with world settings (any field of WorldConfig: scenario, lockstep, "
        "duration_s, act_timeout_ms, truth_rate_hz, ...); environment and flags override it",
    )
    world.add_argument(
        "--scenario",
        metavar="FILE",
        help=f"scenario YAML (default: $SWARM_SCENARIO, else {DEFAULT_SCENARIO})",
    )
    world.add_argument(
        "--lockstep", action="store_true", help="wait for every live robot each tick"
    )
    world.add_argument("--max-speed", type=float, metavar="X", help=MAX_SPEED_HELP)
    world.add_argument("--duration", type=float, metavar="S")
    world.add_argument("--out", metavar="DIR", help="where to write summary.json")
    world.add_argument("--radio", metavar="PROFILE", help="override the scenario's radio profile")
    credentials_option(world, "")
    swarm_options(world)
    world.set_defaults(handler=_cmd_world)

    robot = sub.add_parser(
        "robot",
        help="run one robot process (fabric + firmware)",
        description=(
            "One robot: the FPGA register model and the firmware. Settings fall back to "
            "$ROBOT_NAME (or $ROBOT_ID), $SWARM_SCENARIO, $SWARM_NAME, $ZENOH_CONNECT and "
            "$SWARM_CREDENTIALS_FILE (the path of its credentials file: router login, frame "
            "secret, run id)."
        ),
    )
    robot.add_argument("--name", help="robot name, e.g. robot1")
    robot.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file with robot settings (name, swarm, scenario, connect, "
        "telemetry_rate_hz, ...); environment and flags override it",
    )
    robot.add_argument("--scenario", metavar="FILE")
    credentials_option(robot, "")
    swarm_options(robot)
    robot.set_defaults(handler=_cmd_robot)

    router = sub.add_parser(
        "router",
        help="run the swarm's Zenoh router",
        description="A Zenoh router (configs/zenoh/router.json5 works with zenohd too).",
    )
    router.add_argument(
        "--listen",
        action="append",
        type=endpoint_list,
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable), e.g. tcp/127.0.0.1:7447",
    )
    router.add_argument("--config", metavar="FILE", help="json5 router config")
    router.set_defaults(handler=_cmd_router)

    from services.cli.faults import add_fault_parser

    add_fault_parser(sub, admin_query_options, _cmd_fault)
    if command is not None and command in sub.choices:
        return parser

    from services.dashboard.cli import add_dashboard_parsers
    from services.scenario.cli import add_scenario_parser
    from services.tuner.cli import add_tune_parser

    add_dashboard_parsers(sub)
    add_tune_parser(sub)
    add_scenario_parser(sub)
    return parser


def _run_jit_kernels(command: str | None) -> str | None:
    """Have this process run the control kernels with numba's JIT when `command` is one of
    `JIT_KERNEL_COMMANDS`, even under SWARM_KERNELS=aot: a kernel of the batch simulator or the
    world cannot call a kernel of the ahead-of-time module (numba failed to compile it, "Cannot
    determine Numba type of AotKernel", whenever its cache was cold).  The variable is left as
    it was.  Returns what is wrong when this process already runs them otherwise (a caller of
    `main` that imported them under SWARM_KERNELS=aot), else None."""
    if command not in JIT_KERNEL_COMMANDS:
        return None
    kernels = sys.modules.get("robot_firmware.control.kernels")
    if kernels is not None:
        mode: str = kernels.MODE
        if mode == "jit":
            return None
        return (
            f"this process already runs the control kernels {mode} (${KERNELS_ENV}); swarm "
            f"{command} needs numba's JIT: run it with {KERNELS_ENV} unset or jit"
        )
    wanted = os.environ.get(KERNELS_ENV)
    if wanted != "aot":  # unset and jit are the JIT; another value says so and uses it too
        return None
    os.environ[KERNELS_ENV] = "jit"
    try:
        import robot_firmware.control.kernels  # noqa: F401  (the mode is settled on import)
    finally:
        os.environ[KERNELS_ENV] = wanted
    return None


def main(argv: Sequence[str] | None = None) -> int:
    try:
        set_up_logging()
    except LogLevelError as exc:
        print(f"swarm: {exc}", file=sys.stderr)
        return EXIT_USAGE
    end_with_the_launcher()
    if argv is None:  # this process's own command: a caller's in-process call keeps its SIGINT
        interrupt_once()
    given = sys.argv[1:] if argv is None else list(argv)
    kernels_problem = _run_jit_kernels(given[0] if given else None)
    if kernels_problem is not None:
        print(f"swarm {given[0]}: {kernels_problem}", file=sys.stderr)
        return EXIT_USAGE
    parser = build_parser(given[0] if given else None)
    args = parser.parse_args(given)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    empty_path = empty_path_problem(args)
    if empty_path is not None:
        print(f"swarm {args.command}: {empty_path}", file=sys.stderr)
        return EXIT_USAGE
    # This process's own command goes on when its stdout's device refuses writes (a full disk).
    output = guard_standard_output(args.command) if argv is None else None
    try:
        code: int = args.handler(args)
        if output is not None:
            output.flush()
    except (ScenarioError, UsageError, TlsError, OutputFolderError, SettingsError) as exc:
        print(f"swarm {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except SessionOpenError as exc:  # a process's own Zenoh config that does not wait
        print(f"swarm {args.command}: cannot open its Zenoh session: {exc}", file=sys.stderr)
        return 1
    except FileWriteError as exc:  # a full disk, a quota, a read-only file system
        print(f"swarm {args.command}: {exc}", file=sys.stderr)
        return EXIT_WRITE_FAILED
    except KeyboardInterrupt:
        print(f"swarm {args.command}: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader of our output went away (e.g. `| head`); nothing left to say.
        sys.stderr.close()
        return 0
    except OSError as exc:
        if exc.errno not in UNUSABLE_PATH_ERRNOS:
            raise
        # A path the user gave that no file system call takes: a name over 255 bytes, a path
        # over 4096, a loop of symbolic links (pathlib's exists() and is_dir() raise these).
        print(f"swarm {args.command}: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return EXIT_USAGE
    if output is not None and output.lost is not None and code == 0:
        return EXIT_WRITE_FAILED
    return code


if __name__ == "__main__":
    sys.exit(main())

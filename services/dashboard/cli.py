"""Command-line entry points of the dashboard: `swarm dashboard` and `swarm replay`.

`add_dashboard_parsers(subparsers)` registers both subcommands on any argparse parser; each sets
`handler` to `run_dashboard` or `run_replay`, which take the parsed arguments and return the exit
status (2 for a user mistake, reported in one line without a traceback).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from robot_firmware.net.session import DEFAULT_ENDPOINT, split_endpoints
from services.dashboard.viewer_options import (
    browser_host_argument,
    default_listen_address,
    listen_address_argument,
    server_memory_limit_argument,
)
from services.launcher.run_lock import (
    DASHBOARD_LOCK_FILE_NAME,
    RunDirectoryBusyError,
    RunDirectoryLock,
)
from services.output_folder import OutputFolderError, prepare_output_folder
from services.path_arguments import broken_link_problem
from services.stop_signals import stop_on_signals
from swarm_config.credentials import (
    CREDENTIALS_FILE_ENV,
)
from swarm_config.scenario import DEFAULT_SCENARIO_PATH, ScenarioError, load_scenario
from swarm_config.settings import SettingsError, endpoint_list, tcp_port

EXIT_USAGE = 2
DEFAULT_SCENARIO = str(DEFAULT_SCENARIO_PATH)
DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876


@contextmanager
def _stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """SIGTERM and SIGINT set `stop` while inside; the previous handlers come back after."""
    signals = (signal.SIGTERM, signal.SIGINT)
    previous = {sig: signal.getsignal(sig) for sig in signals}
    stop_on_signals(stop, signals)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _usage_error(command: str, message: str) -> int:
    print(f"swarm {command}: {message}", file=sys.stderr)
    return EXIT_USAGE


def run_dashboard(args: argparse.Namespace) -> int:
    """`swarm dashboard`: stream a running swarm to the web viewer and DIR/dashboard.rrd."""
    # Rerun loads only when a dashboard runs, not for every `swarm` command.
    from services.dashboard.live import DashboardConfig, DashboardService

    given = {
        "scenario": args.scenario,
        "swarm": args.swarm,
        "connect": split_endpoints(args.connect) if args.connect else None,
        "credentials": args.credentials,
        "host": args.host,
        "web_port": args.web_port,
        "grpc_port": args.grpc_port,
        "out_dir": args.out,
        "server_memory_limit": args.memory_limit,
        "bind": args.bind,
    }
    with ExitStack() as held:  # the recording folder's lock, until this function returns
        try:
            # The scenario first: a missing one is the mistake to report, whatever else is
            # wrong.
            scenario_path = args.scenario or os.environ.get("SWARM_SCENARIO") or DEFAULT_SCENARIO
            scenario = load_scenario(Path(scenario_path))
            config = DashboardConfig.from_sources(
                given, config_file=Path(args.config) if args.config else None
            )
            if config.out_dir is not None:
                prepare_output_folder(config.out_dir, "--out")
                lock = RunDirectoryLock.acquire(
                    config.out_dir,
                    "recording folder",
                    "--out DIR",
                    command="swarm dashboard",
                    lock_file_name=DASHBOARD_LOCK_FILE_NAME,
                )
                held.callback(lock.release)
            service = DashboardService(config, scenario)
        except (ScenarioError, SettingsError, OutputFolderError, RunDirectoryBusyError) as exc:
            return _usage_error("dashboard", str(exc))
        except ValueError as exc:
            return _usage_error("dashboard", f"invalid settings: {exc}")

        def ready() -> None:
            print(
                f"dashboard for swarm {config.swarm} ({scenario.name}) at "
                f"{', '.join(config.connect)}"
            )
            print(f"open {service.url}")
            if service.recording_path is not None:
                print(f"recording to {service.recording_path}")
            if service.kept_recording is not None:
                print(f"previous recording kept as {service.kept_recording}")
            if service.kept_recording_cut_bytes:
                print(
                    f"  its last chunk was half written when the dashboard stopped: "
                    f"{service.kept_recording_cut_bytes} bytes cut off its end"
                )
            sys.stdout.flush()

        try:
            with _stop_on_signals(service.stop):
                return service.run(on_ready=ready)
        except (OSError, RuntimeError) as exc:
            return _usage_error(
                "dashboard", f"cannot serve the viewer: {getattr(exc, 'strerror', None) or exc}"
            )


def _not_a_recording_file(path: Path) -> str | None:
    """Why `path` cannot be a recording without reading it (it is no regular file: missing, a
    folder, a device, a link to nothing), else None."""
    try:
        if path.is_file():
            return None
        if path.is_dir():
            return f"{path} is a folder, not a recording (give its .rrd file)"
        if path.exists():
            return f"{path} is not a regular file (a device, FIFO or socket), not a recording"
        broken_link = broken_link_problem(path)
        if broken_link is not None:
            return broken_link
    except OSError as exc:  # a name too long
        return f"{path}: cannot use it ({exc.strerror or exc})"
    return f"{path}: no such recording"


def run_replay(args: argparse.Namespace) -> int:
    """`swarm replay FILE.rrd`: serve a recorded run to the web viewer."""
    from services.dashboard.live import viewer_url
    from services.dashboard.recording_file import looks_like_recording
    from services.dashboard.replay import replay_command, serve_recording, server_memory_limit_for
    from services.listen_ports import check_port_free

    if args.web_port == args.grpc_port:
        return _usage_error(
            "replay",
            f"--web-port and --grpc-port are both {args.web_port}: the web viewer and the data "
            "server each need a port of their own",
        )
    recording = Path(args.recording)
    not_a_recording = _not_a_recording_file(recording)
    if not_a_recording is not None:
        return _usage_error("replay", not_a_recording)
    try:
        recording_readable = looks_like_recording(recording)
    except OSError as exc:
        return _usage_error("replay", f"{recording}: cannot read it ({exc.strerror or exc})")
    if not recording_readable:
        return _usage_error(
            "replay",
            f"{recording} is not a Rerun recording (it does not start as a .rrd file does); "
            "`swarm dashboard --out DIR` records DIR/dashboard.rrd",
        )
    try:
        check_port_free(args.grpc_port)
        check_port_free(args.web_port)
    except OSError as exc:
        return _usage_error("replay", f"cannot serve the viewer: {exc.strerror or exc}")
    limit = args.memory_limit or server_memory_limit_for(recording)
    bind = args.bind if args.bind is not None else default_listen_address(args.host)
    command = replay_command(recording, args.web_port, args.grpc_port, limit, bind)
    stop = threading.Event()
    print(f"replaying {recording}")
    print(f"open {viewer_url(args.host, args.web_port, args.grpc_port)}", flush=True)
    with _stop_on_signals(stop):
        return serve_recording(command, stop)


def _viewer_options(parser: argparse.ArgumentParser, with_defaults: bool = True) -> None:
    """The viewer's ports and host; without defaults (the dashboard) an unset flag leaves the
    value to the settings file or the settings' own default, which are the same numbers."""

    def default(value: object) -> object:
        return value if with_defaults else None

    parser.add_argument(
        "--web-port",
        type=tcp_port,
        default=default(DEFAULT_WEB_PORT),
        help=f"HTTP port of the web viewer (default: {DEFAULT_WEB_PORT})",
    )
    parser.add_argument(
        "--grpc-port",
        type=tcp_port,
        default=default(DEFAULT_GRPC_PORT),
        help=f"port of the gRPC server the viewer reads from (default: {DEFAULT_GRPC_PORT})",
    )
    parser.add_argument(
        "--host",
        type=browser_host_argument,
        default=default("127.0.0.1"),
        help="this machine's name or address as the browser reaches it, used in the printed "
        "URL (default: 127.0.0.1); both ports must be reachable from the browser",
    )
    parser.add_argument(
        "--bind",
        type=listen_address_argument,
        metavar="ADDR",
        help="the address the data (gRPC) server listens on (default: 127.0.0.1 when --host "
        "is this machine, so nothing from elsewhere reads the swarm; 0.0.0.0, every "
        "interface, for any other --host)",
    )


def add_dashboard_parsers(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `dashboard` (handler `run_dashboard`) and `replay` (handler `run_replay`)."""
    dashboard = subparsers.add_parser(
        "dashboard",
        help="live Rerun dashboard of a running swarm (web viewer + .rrd recording)",
        description=(
            "Subscribe to a running swarm (truth, telemetry, liveliness; it never publishes) and "
            "stream it to the Rerun web viewer and to DIR/dashboard.rrd at once: the map with "
            "true poses, trails, desired formation points, reference path and obstacles; the "
            "leader's tracking error (Fig. 12), the formation errors (Fig. 13), the fuzzy-"
            "scheduled PID gains and the radio's delivery ratio and latency, on the simulated "
            "time line. Prints the URL to open. Stops on Ctrl-C or SIGTERM. A previous "
            "DIR/dashboard.rrd is kept as DIR/dashboard-<n>.rrd; if a kill left its last chunk "
            "half written, that chunk is cut off, so every reader opens the file."
        ),
    )
    dashboard.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file with dashboard settings (any field of DashboardConfig: scenario, swarm, "
        "connect, web_port, grpc_port, out_dir, flush_period_s, ...); environment and flags "
        "override it",
    )
    dashboard.add_argument(
        "--scenario",
        metavar="FILE",
        help=f"the swarm's scenario YAML (default: $SWARM_SCENARIO or {DEFAULT_SCENARIO})",
    )
    dashboard.add_argument(
        "--swarm", help="swarm name, the first chunk of every key (default: $SWARM_NAME or lab)"
    )
    dashboard.add_argument(
        "--connect",
        type=endpoint_list,
        metavar="ENDPOINTS",
        help=f"router endpoint(s), comma separated (default: $ZENOH_CONNECT or {DEFAULT_ENDPOINT})",
    )
    dashboard.add_argument(
        "--out",
        metavar="DIR",
        help="write DIR/dashboard.rrd (default: no file, live only)",
    )
    dashboard.add_argument(
        "--credentials",
        metavar="FILE",
        help=f"the dashboard's credentials file (default: ${CREDENTIALS_FILE_ENV}; `swarm up` "
        "writes DIR/credentials/dashboard.json)",
    )
    dashboard.add_argument(
        "--memory-limit",
        type=server_memory_limit_argument,
        metavar="SIZE",
        help="data the gRPC server keeps for viewers that connect late, oldest dropped first: "
        "a number and a unit (B, kB, MB, GB, KiB, MiB, GiB, ...) or a share of this machine's "
        "memory, e.g. 25%% (default: 256MiB)",
    )
    _viewer_options(dashboard, with_defaults=False)
    dashboard.set_defaults(handler=run_dashboard)

    replay = subparsers.add_parser(
        "replay",
        help="open a recorded run (.rrd) in the Rerun web viewer",
        description=(
            "Serve a recording (e.g. DIR/dashboard.rrd of `swarm dashboard`, also one cut off "
            "by a kill) to the Rerun web viewer and print the URL to open; stops on Ctrl-C. "
            "Equivalent: `rerun --serve-web FILE.rrd --port GRPC --web-viewer-port WEB`, or "
            "`rerun FILE.rrd` for the native viewer."
        ),
    )
    replay.add_argument("recording", metavar="FILE.rrd", help="the recording to open")
    replay.add_argument(
        "--memory-limit",
        type=server_memory_limit_argument,
        metavar="SIZE",
        help="gRPC server memory, e.g. 1GiB or 25%% (default: four times the file, at least "
        "256MiB)",
    )
    _viewer_options(replay)
    replay.set_defaults(handler=run_replay)

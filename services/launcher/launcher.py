"""Local launcher: router, world and one process per robot, without Docker.

`Launcher.up` starts the router, the world and every robot of the scenario as child processes
(`python -m services.cli.main ...`), each logging to `<out>/logs/<name>.log`, and supervises
them until the world ends cleanly (its `--duration`), Ctrl-C or SIGTERM, then stops everything
in order (dashboard, robots, world, router), leaving `<out>/summary.json` from the world.

The dashboard (`swarm dashboard`, the live Rerun viewer and `<out>/dashboard.rrd`) starts with
them unless `dashboard=False`.  While it runs, the launcher answers admin queries on
`swarm/<swarm>/admin/launcher/<verb>`: `status` (processes and PIDs), `kill` (SIGKILL a
process: a robot, the world, the dashboard or the router; a power cut), `restart` (start it
again, killing it first if it still runs), `stop` (SIGSTOP: a frozen board that keeps its state)
and `cont` (SIGCONT: it runs on from where it froze); `swarm status|kill|restart` and
`swarm fault` send them.  A stopped process is not a dead one: the supervisor leaves it alone,
and `status` shows it as `stopped` until `cont`, `kill` or `restart`.
A router that dies is started again at once; every other process is a client that waits for
it and reconnects.  A world that dies (crashes, or is killed from outside the launcher) is
started again too, and resumes from its last checkpoint in `<out>/checkpoints/`
(world/checkpoint.py); one that keeps dying within `WORLD_QUICK_DEATH_S` of its start
`WORLD_MAX_QUICK_DEATHS` times in a row ends the run.  A robot that dies, and a process killed
with `kill`, stay down (a power cut) until restarted.
The process factory is injectable so tests can substitute their own.
One launcher runs per run directory (services/launcher/run_lock.py), and its children end with
it, however it ends (services/launcher/orphans.py).

Every run gets fresh credentials (swarm_config/credentials.py) in `<out>/credentials/`: one
file per identity (router, world, launcher, dashboard, operator, each robot), the router's
user file and its config with the run's access control (services/router/access.py).  Each
child is given the path of its own file in `$SWARM_CREDENTIALS_FILE`, never a secret.
With a `tls/HOST:PORT` endpoint the router listens with a certificate for HOST signed by the
run's own CA (swarm_config/tls.py, in `<credentials>/tls/`; one already there is used) and
every child trusts that CA (`$SWARM_TLS_ROOT_CA`, the path of `ca.pem`).

A swarm over several hosts (docs/multi-host.md) is one launcher per host, each with its own
router, all with a copy of one credentials set (`credentials_dir`, made by `swarm credentials
DIR --tls --tls-host HOST`; its run id is the run's, so it is not renewed, and nothing is written
into it): on the world's host `link_listen` (`tls/ADDRESS:PORT`) is where its router also takes
the other hosts' routers, and `only` names the robots started there; on every other host
`link_connect` is the world host's endpoint its router links to, and only the robots of `only`
start there, with no world and no dashboard, until Ctrl-C or SIGTERM.  The router config of
such a run is written to `<out>/router.json5` (services/router/access.py: who may use a link).
"""

from __future__ import annotations

import errno
import logging
import os
import resource
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO
from urllib.parse import quote

import zenoh
from pydantic import ValidationError

from robot_firmware.control.kernels import KERNELS_ENV
from robot_firmware.native import NATIVE_ENV
from robot_firmware.net.admin import AdminQueue, Handler
from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    ContReply,
    KillReply,
    LauncherStatusReply,
    ProcessRequest,
    ProcessStatus,
    RestartReply,
    StopReply,
    refusal_of,
)
from robot_firmware.net.session import open_client
from services.launcher.open_files import open_file_limit_problem, router_files_needed
from services.launcher.orphans import LAUNCHER_PID_ENV
from services.launcher.process_state import STOPPED_STATES, process_state
from services.launcher.run_lock import RunDirectoryBusyError, RunDirectoryLock
from services.listen_ports import bind_problem, endpoint_listen_problem
from services.output_folder import prepare_output_folder
from services.router.access import (
    ROUTER_CONFIG_FILE,
    check_router_links,
    endpoint_host,
    write_router_config,
)
from services.stop_signals import STOP_SIGNALS
from swarm_config.credentials import (
    CREDENTIALS_DIR_NAME,
    CREDENTIALS_FILE_ENV,
    LAUNCHER,
    SERVICE_IDENTITIES,
    CredentialsError,
    credentials_path,
    generate_credential_set,
    read_credential_set,
    write_credential_set,
)
from swarm_config.scenario import snapshot_scenario
from swarm_config.settings import describe_validation_error
from swarm_config.tls import (
    DEFAULT_TLS_HOSTS,
    TLS_ROOT_CA_ENV,
    TlsFiles,
    generate_tls_files,
    read_tls_files,
    tls_dir,
)
from world.checkpoint import CHECKPOINT_DIR_NAME, CheckpointStore
from world.write_failures import EXIT_SUMMARY_NOT_WRITTEN

log = logging.getLogger("swarm.launcher")

ROOT = Path(__file__).resolve().parents[2]
WORLD_QUICK_DEATH_S = 5.0
"""A world that dies sooner than this after its start counts as a quick death."""
WORLD_MAX_QUICK_DEATHS = 5
"""This many quick deaths in a row end the run (a world that cannot start)."""


ROUTER_START_POLL_S = 1.0
"""While the router comes up, the launcher tries to connect for this long at a time, and in
between looks whether the router is still running and whether a stop was asked."""
ROUTER_LOGIN_TIMEOUT_S = 60.0
"""How long the launcher tries to log in to the router it started while that router runs: a
router starts in well under a second, a few on a loaded machine; one that still refuses the
launcher after this (another program's router on the port, a credentials set it was not
started with) will not let it in, and the run stops with the router's log named."""


class LaunchError(Exception):
    """`swarm up` could not bring the swarm up; the message says why and where to look."""


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    process: subprocess.Popen[bytes] | None = None
    log_file: IO[bytes] | None = None
    restarts: int = 0
    killed: bool = False
    stopped: bool = False
    """SIGSTOPped by the launcher and not continued since."""
    started_mono_s: float = 0.0
    exit_reported: bool = False
    """An exit of its own has been reported since its last start."""

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def stopped_now(self) -> bool:
        """Running and stopped by a signal, by the launcher or from outside (`kill -STOP`,
        Ctrl-Z in a terminal of its own), as the kernel says where /proc tells; elsewhere
        what the launcher itself did."""
        if not self.running or self.process is None:
            return False
        state = process_state(self.process.pid)
        return self.stopped if state is None else state in STOPPED_STATES


ProcessFactory = Callable[[list[str], IO[bytes], dict[str, str]], "subprocess.Popen[bytes]"]


def default_factory(
    argv: list[str], log: IO[bytes], env: dict[str, str]
) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=ROOT, start_new_session=True
    )


@dataclass
class LaunchPlan:
    scenario: Path
    robots: Sequence[str]
    out_dir: Path
    swarm: str = "lab"
    endpoint: str = "tcp/127.0.0.1:7447"
    lockstep: bool = False
    max_speed: float | None = None
    duration_s: float | None = None
    radio_profile: str | None = None
    dashboard: bool = True
    web_port: int = 9090
    grpc_port: int = 9876
    extra_env: dict[str, str] = field(default_factory=dict)
    credentials_dir: Path | None = None
    """A credentials set to use (its secrets are kept, its run id renewed, except across hosts);
    None: a fresh set in `<out_dir>/credentials/`."""
    only: Sequence[str] | None = None
    """The robots started on this host (None: all of `robots`); the others run elsewhere."""
    link_listen: Sequence[str] = ()
    """The world's host: `tls/` endpoints where its router also takes other hosts' routers."""
    link_connect: Sequence[str] = ()
    """Another host: the world host's `tls/` endpoint its router links to (no world here)."""

    def __post_init__(self) -> None:
        # The processes start in the repository (`default_factory`), not where `swarm up` was
        # typed: a relative path would name another file there, or none.
        self.scenario = self.scenario.absolute()
        self.out_dir = self.out_dir.absolute()
        if self.credentials_dir is not None:
            self.credentials_dir = self.credentials_dir.absolute()

    @property
    def uses_tls(self) -> bool:
        """Whether the router has a TLS endpoint or link (`tls/HOST:PORT`)."""
        return any(e.startswith("tls/") for e in (self.endpoint, *self.router_links))

    @property
    def endpoint_host(self) -> str:
        """HOST of the endpoint `proto/HOST:PORT` (without an IPv6 address's brackets)."""
        return endpoint_host(self.endpoint)

    @property
    def router_links(self) -> tuple[str, ...]:
        """The endpoints of the router's links to other hosts' routers, either way."""
        return (*self.link_listen, *self.link_connect)

    @property
    def across_hosts(self) -> bool:
        """Whether this host runs only a part of the swarm, the rest on other hosts."""
        return self.only is not None or bool(self.router_links)

    @property
    def runs_dashboard(self) -> bool:
        """Whether this host runs the dashboard (with the world, unless --no-dashboard)."""
        return self.dashboard and self.runs_world

    @property
    def router_listen_endpoints(self) -> tuple[str, ...]:
        """Where this host's router listens: the swarm's endpoint, and across hosts the
        endpoints other hosts' routers link to."""
        if self.across_hosts:
            return (self.endpoint, *self.link_listen)
        return (self.endpoint,)

    @property
    def runs_world(self) -> bool:
        """Whether the world (and the dashboard) runs on this host."""
        return not self.link_connect

    @property
    def started_robots(self) -> tuple[str, ...]:
        """The robots this launcher starts."""
        return tuple(self.robots if self.only is None else self.only)

    def check(self) -> None:
        """ValueError for a plan no launcher can run (what `swarm up` refuses first)."""
        unknown = [name for name in self.started_robots if name not in self.robots]
        if unknown:
            raise ValueError(
                f"no robot {', '.join(map(repr, unknown))} in the scenario; its robots: "
                f"{', '.join(self.robots)}"
            )
        if self.link_connect and not self.started_robots:
            raise ValueError("a host that joins a world elsewhere must start a robot")
        if self.link_connect and self.link_listen:
            raise ValueError("a host either runs the world (link_listen) or joins one elsewhere")
        if self.dashboard and self.runs_world:
            ports = {
                "--port": int(self.endpoint.rpartition(":")[2]),
                "--web-port": self.web_port,
                "--grpc-port": self.grpc_port,
            }
            for flag, port in ports.items():
                same = [other for other, taken in ports.items() if taken == port and other != flag]
                if same:
                    raise ValueError(
                        f"{flag} and {same[0]} are both {port}: the router and the dashboard's "
                        "two servers each need a port of their own"
                    )
        if self.across_hosts and self.credentials_dir is None:
            raise CredentialsError(
                "a swarm across hosts shares one credentials set: make it with `swarm "
                "credentials DIR --tls --tls-host HOST` (HOST: the world host's address), copy "
                "DIR to every host and give it to each `swarm up --credentials DIR`"
            )

    @property
    def viewer_url(self) -> str:
        """The Rerun web viewer's address with its data source filled in."""
        source = quote(f"rerun+http://127.0.0.1:{self.grpc_port}/proxy", safe="")
        return f"http://127.0.0.1:{self.web_port}/?url={source}"


LAST_LINE_BYTES_MAX = 4096
"""How much of a log's end `last_line` reads."""


def last_line(path: Path) -> str:
    """The last non-empty line of a log file (at most 300 characters), or why there is none."""
    try:
        with path.open("rb") as log_file:
            size = log_file.seek(0, os.SEEK_END)
            log_file.seek(max(0, size - LAST_LINE_BYTES_MAX))
            tail = log_file.read().decode("utf-8", errors="replace")
    except OSError as exc:
        return f"none ({path}: {exc.strerror or exc})"
    lines = [line for line in tail.splitlines() if line.strip()]
    return repr(lines[-1][-300:]) if lines else "none (the log is empty)"


def start_problem(plan: LaunchPlan) -> str | None:
    """Why `swarm up` of `plan` cannot start, seen from this host before anything is written or
    started: an open-file limit too low for its router (services/launcher/open_files.py), an
    endpoint the router cannot listen on, a dashboard port taken.  None when nothing is in the
    way.  `swarm up` asks before it touches the run folder, and `Launcher.up` again just before
    it starts the router."""
    # The processes the router lets in: the launcher, the world, the robots, the dashboard.
    clients = 1 + plan.runs_world + len(plan.started_robots) + plan.runs_dashboard
    limit_problem = open_file_limit_problem(router_files_needed(clients))
    if limit_problem is not None:
        return (
            f"{limit_problem} for {clients} processes, so nothing was started (raise it "
            "with `ulimit -n`, or start fewer robots)"
        )
    for endpoint in plan.router_listen_endpoints:
        problem = endpoint_listen_problem(endpoint)
        if problem is not None:
            flag = "--port N" if endpoint == plan.endpoint else "--listen ENDPOINT"
            hint = (
                f" (another program or swarm listens there; `swarm up {flag}` picks another)"
                if problem.errno == errno.EADDRINUSE
                else ""
            )
            return (
                f"cannot listen on {endpoint}: {problem.strerror or problem}, so nothing was "
                f"started{hint}"
            )
    if plan.runs_dashboard:
        for flag, port in (("--web-port", plan.web_port), ("--grpc-port", plan.grpc_port)):
            taken = bind_problem("0.0.0.0", port)
            if taken is not None:
                return (
                    f"the dashboard cannot serve on port {port} ({flag}): "
                    f"{taken.strerror or taken}, so nothing was started (give another "
                    f"{flag}, or --no-dashboard to run without it)"
                )
    return None


class Launcher:
    def __init__(self, plan: LaunchPlan, factory: ProcessFactory = default_factory) -> None:
        self.plan = plan
        self.factory = factory
        self.keys = SwarmKeys(plan.swarm)
        self.children: dict[str, Child] = {}
        self.stop = threading.Event()
        self.world_quick_deaths = 0
        """Deaths of the world within `WORLD_QUICK_DEATH_S` of its start, in a row."""
        self._admin = AdminQueue()
        plan.check()
        self._locks: list[RunDirectoryLock] = []
        try:
            self._prepare()
        except BaseException:
            self._release_directories()
            raise

    def _lock_directories(self) -> list[RunDirectoryLock]:
        """The run directory and the credentials directory this run writes: one `swarm up`
        each (services/launcher/run_lock.py)."""
        plan = self.plan
        # Here, after every check of the plan: a refused run leaves no folder behind.
        prepare_output_folder(plan.out_dir, "--out")
        locks = [RunDirectoryLock.acquire(plan.out_dir, "run directory", "--out DIR")]
        if plan.across_hosts:
            return locks  # every host has its own copy of the set, and none is written
        if plan.credentials_dir is None:
            written, instead = plan.out_dir / CREDENTIALS_DIR_NAME, "--out DIR"
        else:
            written, instead = plan.credentials_dir, "--credentials DIR"
        try:
            locks.append(RunDirectoryLock.acquire(written, "credentials directory", instead))
        except RunDirectoryBusyError:
            locks[0].release()
            raise
        return locks

    def _release_directories(self) -> None:
        for lock in self._locks:
            lock.release()
        self._locks = []

    def _prepare(self) -> None:
        """Credentials, router config and every child's command line."""
        plan = self.plan
        logs = plan.out_dir / "logs"
        # Credentials for this run (a new run id at least); children get their file's path.
        if plan.credentials_dir is None:
            self.credentials_dir = plan.out_dir / CREDENTIALS_DIR_NAME
            self.credentials = generate_credential_set(plan.swarm, plan.robots)
        elif plan.across_hosts:
            # The set every host has a copy of: its run id is the run's, and it stays as it is.
            self.credentials_dir = plan.credentials_dir
            self.credentials = read_credential_set(plan.credentials_dir, plan.robots)
        else:
            self.credentials_dir = plan.credentials_dir
            given = read_credential_set(plan.credentials_dir, plan.robots)
            self.credentials = given.with_new_run_id()
        listen = list(plan.router_listen_endpoints)
        if plan.across_hosts:
            self.tls = read_tls_files(tls_dir(self.credentials_dir)) if plan.uses_tls else None
            check_router_links(plan.link_connect, plan.link_listen, self.tls)
            self._locks = self._lock_directories()  # before the first write
            logs.mkdir(parents=True, exist_ok=True)
            router_config = write_router_config(
                self.credentials_dir,
                self.credentials,
                listen,
                self.tls,
                connect=plan.link_connect,
                accept_routers=bool(plan.link_listen),
                path=plan.out_dir / ROUTER_CONFIG_FILE,
            )
            self.credential_files = {
                identity: credentials_path(self.credentials_dir, identity)
                for identity in (*SERVICE_IDENTITIES, *plan.robots)
            }
        else:
            self._locks = self._lock_directories()  # before the first write
            logs.mkdir(parents=True, exist_ok=True)
            self.credential_files = write_credential_set(self.credentials_dir, self.credentials)
            self.tls = self._tls_files() if plan.uses_tls else None
            router_config = write_router_config(
                self.credentials_dir, self.credentials, listen, self.tls
            )
        # The run's own copy of its scenario: restarts read it, whatever becomes of the file.
        self.scenario_copy = snapshot_scenario(plan.scenario, plan.out_dir)
        scenario = str(self.scenario_copy)
        if plan.runs_world:
            # A world resumes from the checkpoints in its folder: those of an earlier run there
            # would make this run carry on from that one's end (its time, bodies, counters).
            cleared = CheckpointStore(plan.out_dir / CHECKPOINT_DIR_NAME).clear()
            if cleared:
                log.info("a new run in %s: the earlier run's checkpoints removed", plan.out_dir)
        cli = [sys.executable, "-m", "services.cli.main"]
        connect = ["--connect", plan.endpoint, "--swarm", plan.swarm]
        listen_flags = [flag for endpoint in listen for flag in ("--listen", endpoint)]
        self.children["router"] = Child(
            "router",
            [*cli, "router", *listen_flags, "--config", str(router_config)],
            logs / "router.log",
        )
        world = [
            *cli,
            "world",
            "--scenario",
            scenario,
            *connect,
            "--out",
            str(plan.out_dir),
        ]
        if plan.lockstep:
            world.append("--lockstep")
        if plan.max_speed is not None:
            world += ["--max-speed", str(plan.max_speed)]
        if plan.duration_s is not None:
            world += ["--duration", str(plan.duration_s)]
        if plan.radio_profile is not None:
            world += ["--radio", plan.radio_profile]
        if plan.runs_world:
            self.children["world"] = Child("world", world, logs / "world.log")
        for name in plan.started_robots:
            argv = [*cli, "robot", "--name", name, "--scenario", scenario, *connect]
            self.children[name] = Child(name, argv, logs / f"{name}.log")
        if plan.runs_dashboard:
            dashboard = [
                *cli,
                "dashboard",
                "--scenario",
                scenario,
                *connect,
                "--out",
                str(plan.out_dir),
                "--web-port",
                str(plan.web_port),
                "--grpc-port",
                str(plan.grpc_port),
            ]
            self.children["dashboard"] = Child("dashboard", dashboard, logs / "dashboard.log")

    def _tls_files(self) -> TlsFiles:
        """The TLS files in the credentials directory, made now (a new CA) unless a complete
        set is there already."""
        directory = tls_dir(self.credentials_dir)
        if TlsFiles(directory).complete():
            return read_tls_files(directory)
        hosts = tuple(dict.fromkeys((*DEFAULT_TLS_HOSTS, self.plan.endpoint_host)))
        return generate_tls_files(directory, self.plan.swarm, hosts)

    def _env(self, name: str) -> dict[str, str]:
        env = dict(os.environ)
        env.update(self.plan.extra_env)
        env.pop("SWARM_KEY", None)  # secrets never travel in a child's environment
        env[CREDENTIALS_FILE_ENV] = str(self.credential_files[name])
        if name in self.plan.started_robots:
            # Robots run the control kernels compiled ahead of time (no numba in the process);
            # the world and the rest keep numba's JIT (robot_firmware/control/kernels.py).
            env.setdefault(KERNELS_ENV, "aot")
            # and their register model and drivers compiled by mypyc (robot_firmware/native.py).
            env.setdefault(NATIVE_ENV, "mypyc")
        else:
            env[KERNELS_ENV] = "jit"  # the world's own kernels call the control kernels
        if self.tls is not None:
            env[TLS_ROOT_CA_ENV] = str(self.tls.ca_certificate.resolve())
        env["PYTHONUNBUFFERED"] = "1"
        env[LAUNCHER_PID_ENV] = str(os.getpid())  # the child ends with this process
        return env

    def start(self, name: str) -> None:
        """Start `name`'s process.  LaunchError when the host gives no process or log file
        (the open-file limit, memory): the message says which resource."""
        child = self.children[name]
        try:
            if child.log_file is None:
                child.log_file = child.log_path.open("ab")
            child.process = self.factory(child.argv, child.log_file, self._env(name))
        except OSError as exc:
            limit = ""
            if exc.errno in (errno.EMFILE, errno.ENFILE):
                open_files_max = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
                limit = f" (the open-file limit is {open_files_max}: `ulimit -n`)"
            raise LaunchError(f"cannot start {name}: {exc.strerror or exc}{limit}") from None
        child.killed = False
        child.stopped = False
        child.exit_reported = False
        child.started_mono_s = time.monotonic()
        log.info("started %s (pid %d)", name, child.process.pid)

    def kill(self, name: str) -> bool:
        """SIGKILL, as a power cut: no clean-up runs in the child."""
        child = self.children[name]
        if not child.running or child.process is None:
            return False
        child.process.kill()
        child.process.wait()
        child.killed = True
        child.stopped = False
        return True

    def freeze(self, name: str) -> bool:
        """SIGSTOP, a frozen board: the process keeps its state and runs on after `thaw`.
        False when it does not run."""
        child = self.children[name]
        if not child.running or child.process is None:
            return False
        child.process.send_signal(signal.SIGSTOP)
        child.stopped = True
        return True

    def thaw(self, name: str) -> bool:
        """SIGCONT: a stopped process runs on (a running one is unaffected).  False when it
        does not run."""
        child = self.children[name]
        if not child.running or child.process is None:
            return False
        child.process.send_signal(signal.SIGCONT)
        child.stopped = False
        return True

    def restart(self, name: str) -> None:
        self.kill(name)
        self.children[name].restarts += 1
        self.start(name)

    def status(self) -> dict[str, ProcessStatus]:
        return {
            name: ProcessStatus(
                pid=child.process.pid if child.process else None,
                running=child.running,
                exit_code=None
                if child.process is None or child.running
                else child.process.returncode,
                killed=child.killed,
                stopped=child.stopped_now,
                restarts=child.restarts,
                log=str(child.log_path),
            )
            for name, child in self.children.items()
        }

    def _process_named(self, body: bytes) -> str | AdminError:
        try:
            name = ProcessRequest.model_validate_json(body).process
        except ValidationError as exc:
            return AdminError(
                error=describe_validation_error("invalid request", exc), reason=refusal_of(exc)
            )
        if name not in self.children:
            return AdminError(
                error=f"no process {name!r}; processes: {', '.join(self.children)}",
                reason=AdminRefusal.UNKNOWN_PROCESS,
            )
        return name

    def _kill_request(self, body: bytes) -> KillReply | AdminError:
        name = self._process_named(body)
        return name if isinstance(name, AdminError) else KillReply(killed=self.kill(name))

    def missing_to_start(self, name: str) -> str | None:
        """Why `name` could not start from the run folder now, else None: its credentials or
        the run's scenario copy are gone (the folder deleted or moved while the run went on;
        before, a restart said ok and the process ended at once, and the launcher pointed to
        a log in the folder that was gone)."""
        needed = [self.credential_files[name]]
        if name != "router":
            needed.append(self.scenario_copy)
        missing = [path for path in needed if not path.is_file()]
        if not missing:
            return None
        if not self.plan.out_dir.is_dir():
            return (
                f"{name} cannot start: the run folder {self.plan.out_dir} is gone (deleted or "
                f"moved while the run went on), and {missing[0].name} with it"
            )
        return f"{name} cannot start: {missing[0]} is missing (deleted while the run went on)"

    def _restart_request(self, body: bytes) -> RestartReply | AdminError:
        name = self._process_named(body)
        if isinstance(name, AdminError):
            return name
        missing = self.missing_to_start(name)
        if missing is not None:
            return AdminError(error=missing, reason=AdminRefusal.CANNOT_START)
        self.restart(name)
        process = self.children[name].process
        return RestartReply(restarted=name, pid=process.pid if process else None)

    def _stop_request(self, body: bytes) -> StopReply | AdminError:
        name = self._process_named(body)
        return name if isinstance(name, AdminError) else StopReply(stopped=self.freeze(name))

    def _cont_request(self, body: bytes) -> ContReply | AdminError:
        name = self._process_named(body)
        return name if isinstance(name, AdminError) else ContReply(continued=self.thaw(name))

    def admin_handlers(self) -> dict[str, Handler]:
        """The launcher's admin verbs, served from its supervision loop."""
        return {
            "status": lambda _body: LauncherStatusReply(processes=self.status()),
            "kill": self._kill_request,
            "restart": self._restart_request,
            "stop": self._stop_request,
            "cont": self._cont_request,
        }

    def _serve(self) -> None:
        self._admin.serve(self.admin_handlers())

    def _launcher_session(self) -> zenoh.Session | None:
        """The launcher's own session, once the router it started lets it in; None when the
        router exited first (it could not listen: the port taken, a bad endpoint) or a stop
        was asked meanwhile (Ctrl-C works while the router comes up).  LaunchError when the
        router runs but has not let the launcher in within `ROUTER_LOGIN_TIMEOUT_S`."""
        launcher = self.credentials.for_identity(LAUNCHER)
        ca = self.tls.ca_certificate if self.tls is not None else None
        deadline_s = time.monotonic() + ROUTER_LOGIN_TIMEOUT_S
        while not self.stop.is_set():
            try:
                return open_client(
                    [self.plan.endpoint],
                    credentials=launcher,
                    tls_root_ca=ca,
                    connect_timeout_s=ROUTER_START_POLL_S,
                )
            except zenoh.ZError:
                if not self.children["router"].running:
                    return None
                if time.monotonic() > deadline_s:
                    raise LaunchError(
                        f"the router has run for {ROUTER_LOGIN_TIMEOUT_S:.0f} s without letting "
                        f"the launcher in at {self.plan.endpoint}, so nothing else was started: "
                        f"see {self.children['router'].log_path} (does another program answer "
                        "there?)"
                    ) from None
        return None

    def up(self, on_ready: Callable[[], None] | None = None) -> int:
        """Start everything and supervise until the world ends or a stop is asked.

        Raises LaunchError, having stopped what it started, when the router could not listen
        (checked before it starts), exits before it lets the launcher in, or runs
        `ROUTER_LOGIN_TIMEOUT_S` without letting it in, and when the open-file limit is too
        low for the swarm (services/launcher/open_files.py)."""
        problem = start_problem(self.plan)
        if problem is not None:
            self.shutdown()
            raise LaunchError(problem)
        self.start("router")
        try:
            opened = self._launcher_session()
        except LaunchError:
            self.shutdown()
            raise
        if opened is None:
            router = self.children["router"]
            status = None if router.process is None else router.process.poll()
            self.shutdown()
            if self.stop.is_set():
                return 0
            raise LaunchError(
                f"the router exited (status {status}) before it let the launcher in, so nothing "
                f"else was started: see {router.log_path} (is {self.plan.endpoint} taken by "
                "another program or swarm? `swarm up --port N` picks another port)"
            )
        with opened as session:
            session.declare_queryable(self.keys.admin("launcher", "*"), self._admin.on_query)
            token = session.liveliness().declare_token(self.keys.alive("launcher", "launcher"))
            code = 0
            try:  # whatever fails from here, what did start is stopped before the launcher ends
                if "world" in self.children:
                    self.start("world")
                for name in self.plan.started_robots:
                    self.start(name)
                if "dashboard" in self.children:
                    self.start("dashboard")
                if on_ready is not None:
                    on_ready()
                while not self.stop.is_set():
                    self._serve()
                    ended = self.supervise_world()
                    self.report_exits()
                    if ended is not None:
                        code = ended
                        break
                    if not self.children["router"].running:
                        # Clients wait for the router and reconnect: bring it back.
                        log.warning("the router exited; restarting it")
                        self.restart("router")
                    time.sleep(0.05)
            finally:
                token.undeclare()
                self.shutdown()
        return code

    def report_exits(self) -> None:
        """Say once, on the launcher's log, that a robot or the dashboard ended by itself (a
        crash, a port it could not take): it stays down, as a power cut would leave it."""
        for name, child in self.children.items():
            if name in ("world", "router") or child.killed or child.exit_reported:
                continue
            status = None if child.process is None else child.process.poll()
            if status is None:
                continue
            child.exit_reported = True
            log.warning(
                "%s exited by itself (status %d); it stays down until `swarm restart %s`: see %s",
                name,
                status,
                name,
                child.log_path,
            )

    def supervise_world(self) -> int | None:
        """The run's exit status when the world has ended it, else None.

        A clean exit (status 0, or EXIT_SUMMARY_NOT_WRITTEN: the run ended but the final
        summary could not be written) ends the run; a world killed through `kill` stays down
        until `restart`; any other exit is a death, a stop signal from outside the launcher
        (`kill PID`: status 128 + the signal) included: the world is started again (it resumes
        from its checkpoint), unless it died `WORLD_MAX_QUICK_DEATHS` times in a row at its
        start.
        Without a world on this host (it runs elsewhere), None."""
        world = self.children.get("world")
        if world is None:
            return None
        exit_code = None if world.process is None else world.process.poll()
        if exit_code is None or world.killed:
            return None
        if exit_code in (0, EXIT_SUMMARY_NOT_WRITTEN):  # the run ended either way
            return exit_code
        missing = self.missing_to_start("world")
        if missing is not None:
            log.error("the world exited (%d) and %s: ending the run", exit_code, missing)
            return exit_code
        quick = time.monotonic() - world.started_mono_s < WORLD_QUICK_DEATH_S
        self.world_quick_deaths = self.world_quick_deaths + 1 if quick else 0
        if self.world_quick_deaths >= WORLD_MAX_QUICK_DEATHS:
            log.error(
                "the world died %d times at its start; ending (its last log line: %s)",
                self.world_quick_deaths,
                last_line(world.log_path),
            )
            return exit_code
        signum = exit_code - 128
        if signum in STOP_SIGNALS:
            log.warning(
                "the world was stopped by %s from outside this launcher, before the run's end; "
                "restarting it (it resumes from its checkpoint; Ctrl-C here ends the run, "
                "`swarm fault kill world` keeps it down)",
                signal.Signals(signum).name,
            )
        else:
            log.warning("the world exited (%d); restarting it", exit_code)
        self.restart("world")
        return None

    @property
    def world_exit_code(self) -> int | None:
        """The world's exit status once it has ended (None while it runs, or with no world on
        this host)."""
        world = self.children.get("world")
        return None if world is None or world.process is None else world.process.poll()

    def shutdown(self, grace_s: float = 5.0) -> None:
        """SIGTERM every child and wait for it: the dashboard, then the world (so its final
        summary and events are of the run, not of robots going down one by one), then the
        robots, then the router they all talk through."""
        order = [
            n for n in ("dashboard", "world", *self.plan.robots, "router") if n in self.children
        ]
        for name in order:
            child = self.children[name]
            if child.running and child.process is not None:
                child.process.send_signal(signal.SIGTERM)
                # A stopped process acts on SIGTERM once continued, and it may have been
                # stopped from outside (`kill -STOP`) without the launcher knowing: the world
                # would then lose its final summary to the SIGKILL after the grace time.
                child.process.send_signal(signal.SIGCONT)
                child.stopped = False
                try:
                    child.process.wait(timeout=grace_s)
                except subprocess.TimeoutExpired:
                    log.warning("%s did not end within %g s of SIGTERM: killed", name, grace_s)
                    child.process.kill()
                    child.process.wait()
            if child.log_file is not None:
                child.log_file.close()
                child.log_file = None
        self._release_directories()

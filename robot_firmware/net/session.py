"""One place that turns command-line and environment settings into a Zenoh session.

Every process of the swarm is a client of the router (DESIGN.md §2): `client_config` starts
from `configs/zenoh/client.json5` (wait for the router, retry, short lease), overrides the
endpoints and logs in with the process's own user and password (`transport/auth/usrpwd`, from
its credentials file: swarm_config/credentials.py); `router_config` does the same for the
router from `configs/zenoh/router.json5` (or the per-run file `swarm up` generates with the
router's user dictionary and access control: services/router/access.py).

A client given no credentials uses the file named by `$SWARM_CREDENTIALS_FILE` when it is set
(how test harnesses and your own scripts reach a running swarm), and otherwise connects
without any: a router that requires them refuses it.

On `tls/HOST:PORT` endpoints a client trusts the router only if the swarm's CA signed its
certificate for HOST (swarm_config/tls.py): the CA certificate given as `tls_root_ca`, else
the file named by `$SWARM_TLS_ROOT_CA` (`transport/link/tls/root_ca_certificate`), else one
its config file names.  `open_client` refuses a `tls/` endpoint with none of them at once
(`TlsError`): zenoh would otherwise keep retrying a router it can never trust.

Every process runs Zenoh's work on fewer threads than Zenoh's default, unless `$ZENOH_RUNTIME`
already says how.  By default Zenoh gives a process five runtimes of one or two threads each
(app, acc, tx, rx, net), and a message wakes two or three of them in turn; a robot or the world
handles a few hundred small messages a second, and on two cores those hand-overs between
threads cost more than the work (docs/scale.md, "Zenoh on one thread").  A client runs every
runtime on the application runtime's one thread (`CLIENT_ZENOH_RUNTIME`).  The router runs
every runtime on the receive runtime's two threads (`ROUTER_ZENOH_RUNTIME`): it forwards each
message on the receive thread of the link it came on, and a forward to a congested link waits
there, so on one thread a single cut link between hosts stalled every link of the router,
lease checks included (tests/integration/test_multi_host.py); with two, the other goes on.
"""

from __future__ import annotations

import json
import os
import re
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import zenoh

from swarm_config.credentials import CREDENTIALS_FILE_ENV, ProcessCredentials, read_credentials
from swarm_config.settings import SettingsError
from swarm_config.tls import TLS_ROOT_CA_ENV, TlsError, root_ca_from_environment

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "zenoh"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
"""Zenoh's own variable for its runtimes' threads (RON), read once, when a process's first
session starts."""
CLIENT_ZENOH_RUNTIME = (
    "(rx: (handover: app), tx: (handover: app), acc: (handover: app), net: (handover: app))"
)
"""A client's Zenoh runtimes all handed over to the application runtime (one worker thread)."""
ROUTER_ZENOH_RUNTIME = (
    "(app: (handover: rx), tx: (handover: rx), acc: (handover: rx), net: (handover: rx))"
)
"""The router's Zenoh runtimes all handed over to the receive runtime (two worker threads)."""


@contextmanager
def zenoh_runtime_while_opening(setting: str) -> Iterator[None]:
    """Within: $ZENOH_RUNTIME says `setting`, unless it was set already.

    Zenoh reads the variable once, when the process's first session starts, so a session
    opened within keeps that setting; afterwards the variable is gone again, and the processes
    this one starts (the launcher opens a client, then may restart the router) inherit the
    environment it had."""
    if ZENOH_RUNTIME_ENV in os.environ:
        yield
        return
    os.environ[ZENOH_RUNTIME_ENV] = setting
    try:
        yield
    finally:
        os.environ.pop(ZENOH_RUNTIME_ENV, None)


def _load(path: Path | None, default_name: str) -> zenoh.Config:
    """The config in `path` (FileNotFoundError when it names no file), else the project's
    `default_name`, else Zenoh's defaults; zenoh.ZError for a file Zenoh cannot read."""
    if path is not None:
        if not path.is_file():
            raise FileNotFoundError(f"{path}: not a config file (no such file, or not a file)")
        try:
            return zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise SettingsError(
                f"{path}: not a config Zenoh can read ({zenoh_error_text(exc)})"
            ) from None
    source = CONFIG_DIR / default_name
    if source.exists():
        return zenoh.Config.from_file(str(source))
    return zenoh.Config()


def client_config(
    connect: Sequence[str] = (DEFAULT_ENDPOINT,),
    config_file: Path | None = None,
    credentials: ProcessCredentials | None = None,
    tls_root_ca: Path | None = None,
    connect_timeout_s: float | None = None,
) -> zenoh.Config:
    """A client's config; with `credentials`, it logs in as their identity; with
    `tls_root_ca`, it trusts the router certificates that CA signed on `tls/` links; with
    `connect_timeout_s`, opening the session fails (zenoh.ZError) when no router let it in
    within that time, instead of waiting for one as the swarm's processes do."""
    config = _load(config_file, "client.json5")
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if connect_timeout_s is not None:
        config.insert_json5(
            "connect/timeout_ms", json.dumps(max(1, round(connect_timeout_s * 1e3)))
        )
    if credentials is not None:
        login = {"user": credentials.identity, "password": credentials.password.get_secret_value()}
        config.insert_json5("transport/auth/usrpwd", json.dumps(login))
    if tls_root_ca is not None:
        ca = str(tls_root_ca.resolve())
        config.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(ca))
    return config


def credentials_from_environment() -> ProcessCredentials | None:
    """The credentials in the file named by $SWARM_CREDENTIALS_FILE, None when it is unset
    (CredentialsError when it names a file that cannot be used)."""
    path = os.environ.get(CREDENTIALS_FILE_ENV)
    return read_credentials(Path(path)) if path else None


def router_config(
    listen: Sequence[str] | None = None, config_file: Path | None = None
) -> zenoh.Config:
    config = _load(config_file, "router.json5")
    config.insert_json5("mode", json.dumps("router"))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return config


def open_client(
    connect: Sequence[str],
    config_file: Path | None = None,
    credentials: ProcessCredentials | None = None,
    tls_root_ca: Path | None = None,
    connect_timeout_s: float | None = None,
    zenoh_errors_logged: bool = True,
) -> zenoh.Session:
    """A client session logged in with `credentials` (else those of $SWARM_CREDENTIALS_FILE,
    else none), trusting `tls_root_ca` (else $SWARM_TLS_ROOT_CA) on `tls/` links; with the
    default config it waits for the router to come up, with `connect_timeout_s` at most that
    long (then zenoh.ZError: no router there, or it refused the login).

    Zenoh writes its own log to stdout, the log file of a process `swarm up` starts; its errors
    are logged there unless `zenoh_errors_logged` is false, which the command line asks for:
    its stdout is the user's (`swarm status robot1 | jq`), and a refused login would put
    Zenoh's error lines into it beside the command's own one-line answer.  $RUST_LOG still
    turns Zenoh's log on in any process."""
    if zenoh_errors_logged:
        zenoh.init_log_from_env_or("error")
    else:
        zenoh.try_init_log_from_env()
    login = credentials if credentials is not None else credentials_from_environment()
    ca = tls_root_ca if tls_root_ca is not None else root_ca_from_environment()
    config = client_config(connect, config_file, login, ca, connect_timeout_s)
    tls_roots = ("root_ca_certificate", "root_ca_certificate_base64")
    no_ca = all(config.get_json(f"transport/link/tls/{key}") == "null" for key in tls_roots)
    if no_ca and any(endpoint.startswith("tls/") for endpoint in connect):
        raise TlsError(
            f"a tls/ endpoint needs the swarm's CA certificate: set ${TLS_ROOT_CA_ENV} to "
            "its path (<credentials>/tls/ca.pem, written by `swarm credentials --tls` or "
            "`swarm up --tls`)"
        )
    with zenoh_runtime_while_opening(CLIENT_ZENOH_RUNTIME):
        return open_session(config)


STOP_CHECK_PERIOD_S = 0.1
"""How often `open_client_until_stopped` looks at its stop event while Zenoh waits."""


def open_client_until_stopped(
    stop: threading.Event,
    connect: Sequence[str],
    config_file: Path | None = None,
    credentials: ProcessCredentials | None = None,
) -> zenoh.Session | None:
    """`open_client` for a process that waits for its router (a robot, the world), given up
    when `stop` is set first (None).  zenoh.open waits in Rust, deaf to the signal handlers
    that set `stop`: a robot started before its router, or with a wrong endpoint, ignored
    Ctrl-C and SIGTERM until a router came.  So Zenoh waits on a thread of its own, with its
    own retry schedule, while this one looks at `stop`; a process that gives up exits with
    that thread still waiting, as the dashboard's does.  Raises what `open_client` raises."""
    opened: list[zenoh.Session] = []
    failed: list[BaseException] = []
    done = threading.Event()

    def open_it() -> None:
        try:
            opened.append(open_client(connect, config_file, credentials))
        except BaseException as exc:  # handed to the caller's thread, raised there
            failed.append(exc)
        finally:
            done.set()

    threading.Thread(target=open_it, name="zenoh-connect", daemon=True).start()
    while not done.wait(STOP_CHECK_PERIOD_S):
        if stop.is_set():
            return None
    if failed:
        raise failed[0]
    return opened[0]


class SessionOpenError(zenoh.ZError):  # type: ignore[misc]  # final in the stubs only
    """Zenoh could not open the session (no router let it in, and the config said not to wait
    for one; a router that cannot listen); a zenoh.ZError still, for the callers that retry,
    with Zenoh's message less its Rust source location."""


RUST_SOURCE_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?\s*$")
"""The ` at /root/.cargo/.../orchestrator.rs:447.` that ends Zenoh's error messages."""


def zenoh_error_text(exc: BaseException) -> str:
    """Zenoh's message for `exc` without the Rust source location it ends with."""
    return RUST_SOURCE_LOCATION.sub("", str(exc))


def open_session(config: zenoh.Config) -> zenoh.Session:
    """`zenoh.open`, with a $ZENOH_RUNTIME that Zenoh cannot read reported as the setting it
    is (SettingsError): Zenoh panics on one when its first session starts, a traceback from
    Rust in every process of the swarm.  SessionOpenError when Zenoh gives up on the session:
    a user's own $ZENOH_CONFIG may say not to wait for the router, as the project's does."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise SessionOpenError(zenoh_error_text(exc)) from None
    except BaseException as exc:  # pyo3's PanicException derives from BaseException only
        if type(exc).__name__ != "PanicException" or ZENOH_RUNTIME_ENV not in os.environ:
            raise
        raise SettingsError(
            f"${ZENOH_RUNTIME_ENV}={os.environ[ZENOH_RUNTIME_ENV]!r} is not a runtime setting "
            f"Zenoh can read ({exc}); unset it, and every process runs Zenoh on the threads "
            "it chooses (robot_firmware/net/session.py)"
        ) from None


def split_endpoints(text: str) -> list[str]:
    """'tcp/a:7447, tcp/b:7447' -> ['tcp/a:7447', 'tcp/b:7447']."""
    return [part.strip() for part in text.split(",") if part.strip()]

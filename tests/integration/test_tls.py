"""TLS links, on loopback only: a real router process on `tls/127.0.0.1:<free port>` with the
run's generated certificates, login and access control on, and clients that do or do not
trust its CA.

Tried, each printed with what happened (pytest -s):
* two clients with the CA and their credentials: connect, and a put of robot1's telemetry
  reaches the operator's subscriber;
* with the CA but no credentials: refused (login stays on over TLS);
* with no CA (zenoh's default roots), with another swarm's CA, plain `tcp/` to the TLS port,
  and a router certificate made for another host: none connects;
* `swarm up --tls --lockstep --duration 3`: a whole run over TLS leaves a summary.json with
  no collision.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import client_config
from services.router.access import write_router_config
from swarm_config.credentials import (
    OPERATOR,
    CredentialSet,
    ProcessCredentials,
    generate_credential_set,
    write_credential_set,
)
from swarm_config.tls import TlsFiles, generate_tls_files
from tests.integration.conftest import ROOT, free_port, run_swarm

pytestmark = pytest.mark.slow

SWARM = "lab"
KEYS = SwarmKeys(SWARM)
ROBOTS = ("robot1", "robot2")
CONNECT_TIMEOUT_MS = 3000
ROUTER_UP_TIMEOUT_S = 30.0
DELIVERY_TIMEOUT_S = 10.0


@dataclass
class TlsRouter:
    endpoint: str
    credentials: CredentialSet
    tls: TlsFiles


def _start_router(config: Path, log_path: Path) -> subprocess.Popen[bytes]:
    with log_path.open("wb") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "services.cli.main", "router", "--config", str(config)],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )


def _wait_listening(process: subprocess.Popen[bytes], log_path: Path) -> None:
    deadline = time.monotonic() + ROUTER_UP_TIMEOUT_S
    while time.monotonic() < deadline:
        if "router listening" in log_path.read_text(errors="replace"):
            return
        assert process.poll() is None, log_path.read_text(errors="replace")
        time.sleep(0.1)
    raise AssertionError(f"router not up in {ROUTER_UP_TIMEOUT_S} s: {log_path.read_text()}")


def _stop(process: subprocess.Popen[bytes]) -> None:
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


@pytest.fixture
def tls_router(tmp_path: Path) -> Iterator[TlsRouter]:
    """A router process listening only on TLS, with login and the run's access control."""
    credentials = generate_credential_set(SWARM, ROBOTS)
    directory = tmp_path / "credentials"
    write_credential_set(directory, credentials)
    tls = generate_tls_files(directory / "tls", SWARM)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    config = write_router_config(directory, credentials, [endpoint], tls)
    log_path = tmp_path / "router.log"
    process = _start_router(config, log_path)
    try:
        _wait_listening(process, log_path)
        yield TlsRouter(endpoint, credentials, tls)
    finally:
        _stop(process)


def _open(
    endpoint: str, credentials: ProcessCredentials | None, root_ca: Path | None
) -> zenoh.Session:
    """A client that fails fast instead of waiting for the router."""
    config = client_config([endpoint], None, credentials, root_ca)
    config.insert_json5("connect/timeout_ms", json.dumps(CONNECT_TIMEOUT_MS))
    return zenoh.open(config)


def _refused(
    what: str, endpoint: str, credentials: ProcessCredentials | None, ca: Path | None
) -> bool:
    """Try to connect; print and return whether zenoh refused."""
    try:
        session = _open(endpoint, credentials, ca)
    except zenoh.ZError as exc:
        print(f"tried {what}: refused ({str(exc).split('!')[0]}!)")
        return True
    session.close()
    print(f"tried {what}: CONNECTED")
    return False


def test_client_trusting_the_ca_exchanges_data_over_tls(tls_router: TlsRouter) -> None:
    robot = tls_router.credentials.for_identity("robot1")
    operator = tls_router.credentials.for_identity(OPERATOR)
    ca = tls_router.tls.ca_certificate
    received: queue.Queue[bytes] = queue.Queue()
    key = KEYS.telemetry("robot1")
    payload = b"telemetry over tls"
    with (
        _open(tls_router.endpoint, operator, ca) as listener,
        _open(tls_router.endpoint, robot, ca) as talker,
    ):
        subscriber = listener.declare_subscriber(key, lambda s: received.put(s.payload.to_bytes()))
        deadline = time.monotonic() + DELIVERY_TIMEOUT_S
        got: bytes | None = None
        while got is None and time.monotonic() < deadline:
            talker.put(key, payload)  # repeated: the subscription may not have reached it yet
            with contextlib.suppress(queue.Empty):
                got = received.get(timeout=0.2)
        subscriber.undeclare()
    print(f"tried robot1 put -> operator subscriber over {tls_router.endpoint}: got {got!r}")
    assert got == payload


def test_login_stays_required_over_tls(tls_router: TlsRouter) -> None:
    ca = tls_router.tls.ca_certificate
    assert _refused("TLS with the CA, no credentials", tls_router.endpoint, None, ca)


def test_clients_not_trusting_the_router_cannot_connect(
    tls_router: TlsRouter, tmp_path: Path
) -> None:
    operator = tls_router.credentials.for_identity(OPERATOR)
    other_ca = generate_tls_files(tmp_path / "other-tls", "other").ca_certificate
    plain = tls_router.endpoint.replace("tls/", "tcp/", 1)
    refused = {
        "no CA": _refused("TLS, no CA (default roots)", tls_router.endpoint, operator, None),
        "other CA": _refused("TLS, another swarm's CA", tls_router.endpoint, operator, other_ca),
        "plain tcp": _refused("plain tcp/ to the TLS port", plain, operator, None),
    }
    assert refused == {"no CA": True, "other CA": True, "plain tcp": True}


def test_router_certificate_for_another_host_is_refused(tmp_path: Path) -> None:
    credentials = generate_credential_set(SWARM, ROBOTS)
    directory = tmp_path / "credentials"
    write_credential_set(directory, credentials)
    tls = generate_tls_files(directory / "tls", SWARM, hosts=("10.9.9.9", "router.example"))
    endpoint = f"tls/127.0.0.1:{free_port()}"
    config = write_router_config(directory, credentials, [endpoint], tls)
    log_path = tmp_path / "router.log"
    process = _start_router(config, log_path)
    try:
        _wait_listening(process, log_path)
        operator = credentials.for_identity(OPERATOR)
        what = "TLS with the CA to a router certified for 10.9.9.9 and router.example only"
        assert _refused(what, endpoint, operator, tls.ca_certificate)
    finally:
        _stop(process)


def test_swarm_up_over_tls_runs_to_its_summary(tmp_path: Path) -> None:
    summary = run_swarm(tmp_path, "--tls", "--lockstep", "--duration", "3")
    tls = TlsFiles(tmp_path / "credentials" / "tls")
    router_text = (tmp_path / "credentials" / "router.json5").read_text()
    router = json.loads(router_text.split("\n", 1)[1])  # after the comment line
    print(
        f"swarm up --tls: {summary['duration_s']} s simulated, collisions "
        f"{summary['collisions']}, TLS files complete: {tls.complete()}"
    )
    assert tls.complete()
    assert all(endpoint.startswith("tls/") for endpoint in router["listen"]["endpoints"])
    assert router["transport"]["link"]["tls"]["listen_certificate"] == str(
        tls.router_certificate.resolve()
    )
    assert summary["duration_s"] == pytest.approx(3.0, abs=0.1)
    assert summary["collisions"] == 0

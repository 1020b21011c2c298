"""The listen probe: a port something listens on is reported, with the reason, before a
router or viewer would meet it; a free port and unprobed protocols pass."""

from __future__ import annotations

import errno
import socket
from collections.abc import Iterator

import pytest

from services.listen_ports import bind_problem, check_port_free, endpoint_listen_problem


@pytest.fixture
def listening_port() -> Iterator[int]:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        yield int(taken.getsockname()[1])


def test_a_port_something_listens_on_is_reported_as_in_use(listening_port: int) -> None:
    for endpoint in (f"tcp/127.0.0.1:{listening_port}", f"tls/127.0.0.1:{listening_port}"):
        problem = endpoint_listen_problem(endpoint)
        assert problem is not None and problem.errno == errno.EADDRINUSE, endpoint
    with pytest.raises(OSError, match=f"port {listening_port} is in use"):
        check_port_free(listening_port)


def test_a_free_port_passes_and_stays_free() -> None:
    with socket.socket() as chosen:
        chosen.bind(("127.0.0.1", 0))
        port = int(chosen.getsockname()[1])
    assert endpoint_listen_problem(f"tcp/127.0.0.1:{port}") is None
    assert bind_problem("127.0.0.1", port) is None
    with socket.socket() as again:  # the probe left nothing bound
        again.bind(("127.0.0.1", port))


def test_an_address_not_on_this_machine_is_reported() -> None:
    problem = endpoint_listen_problem("tcp/192.0.2.1:7447")  # TEST-NET-1, never local
    assert problem is not None and problem.errno == errno.EADDRNOTAVAIL


@pytest.mark.parametrize(
    "endpoint", ["udp/127.0.0.1:7447", "unixsock-stream//tmp/s", "tcp/nohost", "garbage"]
)
def test_what_the_probe_cannot_judge_is_left_to_the_listener(endpoint: str) -> None:
    assert endpoint_listen_problem(endpoint) is None

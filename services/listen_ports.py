"""Whether a port a process is about to listen on is free, asked before the process starts.

A Zenoh router that cannot listen exits only after the launcher's own session has tried the
port, and if another swarm's router answers there, Zenoh logs that router's refusals on the
user's terminal first; Rerun's servers log a taken port and run without it.  A bind probe
(`SO_REUSEADDR`, so a port in TIME_WAIT passes as it does for the real listener) says it in one
line before anything starts.  A probe and a listener are not atomic: a port taken in between
still fails where it did before, in the process that listens.
"""

from __future__ import annotations

import socket

from swarm_config.settings import endpoint_problem

PROBED_PROTOCOLS = ("tcp", "tls")
"""Endpoints whose address is a TCP HOST:PORT on this machine."""


def bind_problem(host: str, port: int) -> OSError | None:
    """The error binding a TCP socket on (host, port) gives now, or None if it would work.  A
    host this machine cannot resolve gives None: the listener will say what is wrong."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror:
        return None
    family, kind, protocol, _, address = addresses[0]
    with socket.socket(family, kind, protocol) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            return exc
    return None


def check_port_free(port: int, host: str = "0.0.0.0") -> None:
    """OSError naming the port if something already listens on it."""
    problem = bind_problem(host, port)
    if problem is not None:
        raise OSError(problem.errno, f"port {port} is in use ({problem.strerror})")


def endpoint_listen_problem(endpoint: str) -> OSError | None:
    """The error a router listening on a tcp/ or tls/ endpoint would meet now, or None (other
    protocols, and endpoints that are not HOST:PORT, are not probed)."""
    protocol, _, rest = endpoint.partition("/")
    if protocol not in PROBED_PROTOCOLS or endpoint_problem(endpoint) is not None:
        return None
    host, _, port = rest.split("?", 1)[0].split("#", 1)[0].rpartition(":")
    return bind_problem(host.removeprefix("[").removesuffix("]"), int(port))

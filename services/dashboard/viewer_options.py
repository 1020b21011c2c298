"""The viewer's host, the address its data server listens on and the gRPC server's memory limit,
checked before anything starts.

`--host` only goes into the printed URL and the CORS origin, so a wrong one (a wildcard, a URL,
a name with a space) used to give a URL no browser opens, with no error; an IPv6 address needs
brackets in a URL.  `--memory-limit` went to Rerun unchecked, which refused it only after the
dashboard had joined the swarm, in its own words.  Each check here raises `ValueError` with the
reason (a settings validator reports it under the field's name); `*_argument` wraps it for
argparse, where the flag is named.

`--bind` is the address the data server listens on.  Rerun's own default is every interface,
which let anyone who reached the machine stream the swarm's truth and telemetry from the
dashboard while the router let nobody in without credentials: the default is now the loopback
address when `--host` is this machine, and every interface only when the browser is elsewhere.
"""

from __future__ import annotations

import argparse
import ipaddress
import re

from swarm_config.tls import is_dns_name

MEMORY_SIZE = re.compile(r"(?P<number>\d+(?:\.\d+)?)\s*(?P<unit>B|kB|KiB|MB|MiB|GB|GiB|TB|TiB|%)")
"""A memory size as Rerun reads it, e.g. 256MiB, 1.5GB, 50% (of this machine's memory)."""


def browser_host(text: str) -> str:
    """The host a browser reaches the viewer at, as it goes into a URL: a DNS name, an IPv4
    address, or an IPv6 address (bracketed, with or without brackets as given)."""
    host = text.strip()
    bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        address = ipaddress.ip_address(bare)
    except ValueError:
        address = None
    if address is not None:
        if address.is_unspecified:
            raise ValueError(
                f"{text!r} is the any-address, which a browser cannot open; give this "
                "machine's name or address as the browser reaches it"
            )
        return f"[{address.compressed}]" if address.version == 6 else address.compressed
    if not is_dns_name(host):
        raise ValueError(
            f"{text!r} is not a host name or address (e.g. 127.0.0.1, robots-lab.local, "
            "[::1]); give the host only, without a scheme, port or path"
        )
    return host


LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "[::1]"})
"""`--host` values that name this machine to a browser on it."""


def listen_address(text: str) -> str:
    """An IP address to listen on (`--bind`): IPv4 or IPv6, without brackets; 0.0.0.0 or ::
    for every interface."""
    bare = text.strip()
    if bare.startswith("[") and bare.endswith("]"):
        bare = bare[1:-1]
    try:
        return ipaddress.ip_address(bare).compressed
    except ValueError:
        raise ValueError(
            f"{text!r} is not an IP address to listen on (e.g. 127.0.0.1, 0.0.0.0 for every "
            "interface, ::1)"
        ) from None


def default_listen_address(host: str) -> str:
    """Where the data server listens when no `--bind` is given: the loopback address for a
    browser on this machine (`host` in LOOPBACK_HOSTS), else every interface, so that the
    browser at `host` reaches it."""
    if host == "[::1]":
        return "::1"
    return "127.0.0.1" if host in LOOPBACK_HOSTS else "0.0.0.0"  # a browser elsewhere


def server_memory_limit(text: str) -> str:
    """A memory size Rerun's gRPC server takes (`MEMORY_SIZE`; a percentage at most 100),
    returned as given."""
    match = MEMORY_SIZE.fullmatch(text.strip())
    if match is None:
        raise ValueError(
            f"{text!r} is not a memory size: a number and a unit, e.g. 256MiB, 2GB or 25% "
            "(units B, kB, MB, GB, TB, KiB, MiB, GiB, TiB)"
        )
    if match["unit"] == "%" and float(match["number"]) > 100.0:
        raise ValueError(f"{text!r}: a share of this machine's memory is at most 100%")
    return text


def browser_host_argument(text: str) -> str:
    """`browser_host` as an argparse type."""
    try:
        return browser_host(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def server_memory_limit_argument(text: str) -> str:
    """`server_memory_limit` as an argparse type."""
    try:
        return server_memory_limit(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def listen_address_argument(text: str) -> str:
    """`listen_address` as an argparse type."""
    try:
        return listen_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None

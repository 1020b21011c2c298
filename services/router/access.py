"""The router's per-run config: who may log in, and what each identity may do (DESIGN.md §7.1).

`router_config_document` builds, for one run, the whole router config (the settings of
configs/zenoh/router.json5, plus):

* `transport/auth/usrpwd`: every client must log in with a user and password listed in the
  run's `router-users.txt` (swarm_config/credentials.py); no login, no session;
* `transport/unicast`: room for `ROUTER_ACCEPT_PENDING` logins at once, each given at most
  `ROUTER_ACCEPT_TIMEOUT_MS` (idle connections held open to the port no longer keep every
  new login out);
* `access_control` with `default_permission: "deny"`: a message passes the router only when
  an allow rule of the sending identity (`ingress`) *and*, where it is delivered to another
  client, of the receiving identity (`egress`) covers its key. A denied message is dropped
  without a word to the sender;
* with the swarm's TLS files (swarm_config/tls.py), `transport/link/tls`: the router's
  certificate and key for its `tls/` endpoints; login and access control stay as above.

What each identity may do (every key from robot_firmware/net/keys.py):

| identity  | sends (ingress)                                      | receives (egress)            |
|-----------|------------------------------------------------------|------------------------------|
| robotN    | put wire/N/act, radio/tx/N, telemetry/N; token       | put wire/N/sense, radio/rx/N,|
|           | alive/robot/N; subscribe wire/N/sense, radio/rx/N,   | clock; queries on admin/N/*; |
|           | clock, tokens alive/robot/*; serve (queryable,       | robot tokens                 |
|           | reply) admin/N/*                                     |                              |
| world     | put wire/*/sense, radio/rx/*, clock, truth; token    | put wire/*/act, radio/tx/*,  |
|           | alive/world/world; subscribe wire/*/act, radio/tx/*, | telemetry/*; robot tokens;   |
|           | telemetry/*, tokens alive/robot/*; serve admin/world | queries on admin/world/*     |
| launcher  | token alive/launcher/launcher; serve admin/launcher  | queries on admin/launcher/*  |
| dashboard | subscribe truth, telemetry/*, tokens alive/**        | put truth, telemetry/*;      |
|           |                                                      | tokens alive/**              |
| operator  | query admin/**; subscribe anything of the swarm      | replies on admin/**; put and |
|           |                                                      | tokens of anything           |
| router    | nothing (no second router in a run)                  | nothing                      |

Admin verbs: only the operator may send queries at all, so the state-changing verbs (`regs`
write, `params` with a body, `net set`, the launcher's `kill` and `restart`) are the
operator's alone. An ACL rule sees a query's key, not its body, so it cannot tell `regs` read
from `regs` write on the same key; since no identity but the operator needs to ask anything,
no split of the verbs' keys is needed. (A read-only monitoring identity would need one.)
The one exception is the world, the swarm's fault hub: it forwards the faults it is sent to a
robot's `admin/N/fault` and to the launcher's `kill`, `stop`, `cont` and `restart`, so it may
query exactly those keys. It also publishes the run's `events`, which the dashboard reads.

Robots and the world may also receive every subscriber declaration of the swarm
(`declare_subscriber` egress on `swarm/<swarm>/**`): a Zenoh publisher sends only when it
knows of a matching subscriber, and the subscriptions it must hear of are wider than its own
key (the world subscribes to `wire/*/act`), which an ACL rule for `wire/robot1/act` does not
cover. What they learn is which key expressions someone subscribes to, never data.

**Router links between hosts** (docs/multi-host.md).  A swarm over several hosts has one
router per host; every process is a client of its own host's router, with the identities and
rules above.  The world's host runs the *hub*: its router also listens on a `tls/` endpoint
(`accept_routers`), where the other hosts' routers log in as `router` with the router's
password.  What a link may carry is checked at both of its ends:

* at the hub, a linked router speaks for the robots of its host: it may do what the robots may
  do (the union of their rules, the `router` row below), and nothing of the world, launcher,
  dashboard or operator; a second host's launcher stays local to that host;
* at another host's router (`connect`: the hub's `tls/HOST:PORT`), the link is the one whose
  TLS peer shows the swarm's router certificate (its common name, `cert_common_names`): the
  only certificate the swarm's CA ever signed (swarm_config/tls.py).  What comes from the hub
  passed the hub's rules already, so the link may carry anything of the swarm's keys; what the
  host's own clients send passes their own rules first.

Links between hosts run over TLS only: a `tcp/` link would show no certificate, so the second
host could not tell its hub from any other client.  Routers with links announce a lease of
`ROUTER_LINK_LEASE_MS`, like the clients (configs/zenoh/client.json5): a host cut off is seen
gone, its robots' tokens with it, after about a second.

| router of   | subject (how the link is recognised) | may                                  |
|-------------|--------------------------------------|--------------------------------------|
| one host    | `router` (user name)                 | nothing (no second router)           |
| the hub     | `router` (user name)                 | what the robots may do, both flows   |
| another host| `hub` (the router certificate's CN)  | anything under `swarm/<swarm>/**`    |

**Sizes.**  An identity that may put on a key may put anything there, of any size: a robot
could hand the world, the dashboard and the router a 50 MB "telemetry sample" to take in.
The router drops what no process of the swarm ever sends, with Zenoh's own limits, before
routing it (so no subscriber sees it and nobody counts it):

* `transport/link/rx/max_message_size` (`MESSAGE_BYTES_MAX`, 1 MiB): a message bigger than
  that is dropped while it arrives, fragment by fragment, so the router never holds it whole;
  the largest message a run sends is a robot's register dump (about 15 KB);
* `low_pass_filter` on the keys the robots put on (`robot_put_limits`, ingress): act pins
  and radio frames at most 1 KiB (they are 44 and 100 bytes), telemetry at most 64 KiB (a
  sample is about 2 KB, and nothing in it grows with the swarm).

A message at a limit passes; one byte over does not (tests/integration/test_security.py).
"""

from __future__ import annotations

import ipaddress
import json
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from robot_firmware.net.keys import SwarmKeys
from swarm_config.credentials import (
    DASHBOARD,
    LAUNCHER,
    OPERATOR,
    ROUTER,
    ROUTER_USERS_FILE,
    WORLD,
    CredentialSet,
    write_private_file,
)
from swarm_config.tls import OPENSSL_TIMEOUT_S, TlsError, TlsFiles, find_openssl

ROUTER_CONFIG_FILE = "router.json5"
"""The generated router config, beside the credentials (it names the user file)."""
HUB = "hub"
"""The subject, on another host's router, of its link to the world host's router."""
ROUTER_LINK_LEASE_MS = 1000
"""The lease a router with links to other hosts announces: a silent link is closed after it."""
ROUTER_LINK_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
"""How often another host's router tries the hub again, while it is unreachable."""
ROUTER_ACCEPT_PENDING = 1000
"""Connections the router lets be in their handshake (login) at once; Zenoh's default is 100.
Anyone who can reach the port holds one with an idle TCP connection, so a hundred of them
(a flood, a scan that keeps its sockets) kept every new login out, a restarted robot's and the
operator's included, until they timed out."""
ROUTER_ACCEPT_TIMEOUT_MS = 5000
"""How long one connection may take for its handshake before the router drops it; Zenoh's
default is 10 s.  A login on loopback takes milliseconds, one over TLS between hosts a few
round trips."""
EVERY_MESSAGE = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)

MESSAGE_BYTES_MAX = 1 << 20
"""The largest message the router takes off any link (module docstring, "Sizes")."""
ACT_AND_FRAME_BYTES_MAX = 1 << 10
"""The largest act message or radio frame a robot may put (they are 44 and 100 bytes)."""
TELEMETRY_BYTES_MAX = 64 << 10
"""The largest telemetry sample a robot may put (a sample is about 2 KB)."""

Flow = Literal["ingress", "egress"]


@dataclass
class Grants:
    """One identity's allowed messages per flow: (message, flow) -> key expressions."""

    allowed: dict[tuple[str, Flow], list[str]] = field(default_factory=dict)

    def allow(self, flow: Flow, messages: Sequence[str], *key_exprs: str) -> None:
        for message in messages:
            self.allowed.setdefault((message, flow), []).extend(key_exprs)


PUBLISH = ("put", "delete")
SUBSCRIBE = ("declare_subscriber",)
SERVE = ("declare_queryable", "reply")


def _publisher(grants: Grants, *key_exprs: str) -> None:
    grants.allow("ingress", PUBLISH, *key_exprs)


def _subscriber(grants: Grants, *key_exprs: str) -> None:
    grants.allow("ingress", SUBSCRIBE, *key_exprs)
    grants.allow("egress", PUBLISH, *key_exprs)


def _server(grants: Grants, key_expr: str) -> None:
    grants.allow("ingress", SERVE, key_expr)
    grants.allow("egress", ("query",), key_expr)


def _token(grants: Grants, key_expr: str) -> None:
    grants.allow("ingress", ("liveliness_token",), key_expr)
    grants.allow("egress", ("declare_liveliness_subscriber",), key_expr)


def _token_watcher(grants: Grants, key_expr: str) -> None:
    grants.allow("ingress", ("declare_liveliness_subscriber", "liveliness_query"), key_expr)
    grants.allow("egress", ("liveliness_token",), key_expr)


def identity_grants(
    swarm: str, robots: Sequence[str], accept_routers: bool = False
) -> dict[str, Grants]:
    """What each identity of a run of `robots` on `swarm` may do (the table above); with
    `accept_routers` (the hub of a swarm over hosts), `router` may do what the robots may."""
    keys = SwarmKeys(swarm)
    grants: dict[str, Grants] = {}
    for name in robots:
        robot = grants[name] = Grants()
        _publisher(robot, keys.act(name), keys.radio_tx(name), keys.telemetry(name))
        _subscriber(robot, keys.sense(name), keys.radio_rx(name), keys.clock)
        _server(robot, keys.admin(name, "*"))
        _token(robot, keys.alive("robot", name))
        # A robot's peers' tokens tell its leader election that a peer is gone at once
        # (robot_firmware/leadership.py), rather than after the frames' time-out.
        _token_watcher(robot, keys.alive_all("robot"))
    world = grants[WORLD] = Grants()
    _publisher(world, keys.sense("*"), keys.radio_rx("*"), keys.clock, keys.truth)
    _subscriber(world, keys.act_all, keys.radio_tx_all, keys.telemetry_all)
    _token_watcher(world, keys.alive_all("robot"))
    _server(world, keys.admin(WORLD, "*"))
    _token(world, keys.alive(WORLD, WORLD))
    _publisher(world, keys.events())
    # The fault hub (world/faults.py): register faults go to a robot's `fault` verb, process
    # faults to the launcher's verbs; the world hears their answers.
    forwarded = [keys.admin(name, "fault") for name in robots]
    forwarded += [keys.admin(LAUNCHER, verb) for verb in ("kill", "stop", "cont", "restart")]
    world.allow("ingress", ("query",), *forwarded)
    world.allow("egress", ("reply",), *forwarded)
    launcher = grants[LAUNCHER] = Grants()
    _server(launcher, keys.admin(LAUNCHER, "*"))
    _token(launcher, keys.alive(LAUNCHER, LAUNCHER))
    dashboard = grants[DASHBOARD] = Grants()
    _subscriber(dashboard, keys.truth, keys.telemetry_all, keys.events())
    _token_watcher(dashboard, keys.everything_under("alive"))
    operator = grants[OPERATOR] = Grants()
    operator.allow("ingress", ("query",), keys.everything_under("admin"))
    operator.allow("egress", ("reply", "declare_queryable"), keys.everything_under("admin"))
    _subscriber(operator, keys.everything)
    _token_watcher(operator, keys.everything_under("alive"))
    grants[ROUTER] = Grants()
    for identity in (*robots, WORLD):
        # A publisher learns whether anyone subscribes from the subscribers' declarations,
        # whose keys are often wider than its own (`wire/*/act`): it may see all of them.
        grants[identity].allow("egress", SUBSCRIBE, keys.everything)
    if accept_routers:
        # Another host's router speaks for the robots of its host, whichever they are.
        for name in robots:
            for (message, flow), key_exprs in grants[name].allowed.items():
                grants[ROUTER].allow(flow, (message,), *key_exprs)
    return grants


def hub_link_grants(swarm: str) -> Grants:
    """What another host's router lets its link to the hub carry: anything of the swarm (the
    hub checked it against its own rules)."""
    grants = Grants()
    for flow in ("ingress", "egress"):
        grants.allow(flow, EVERY_MESSAGE, SwarmKeys(swarm).everything)
    return grants


def access_control(
    swarm: str,
    robots: Sequence[str],
    accept_routers: bool = False,
    hub_common_name: str | None = None,
) -> dict[str, Any]:
    """The `access_control` section: default deny, one subject and its rules per identity;
    with `hub_common_name` (another host's router), also the `hub` subject: the link whose TLS
    peer shows a certificate of that common name."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    identities: list[tuple[str, Grants, dict[str, Any]]] = [
        (identity, grants, {"usernames": [identity]})
        for identity, grants in identity_grants(swarm, robots, accept_routers).items()
    ]
    if hub_common_name is not None:
        identities.append((HUB, hub_link_grants(swarm), {"cert_common_names": [hub_common_name]}))
    for identity, grants, match in identities:
        subjects.append({"id": identity, **match})
        rule_ids = []
        for (message, flow), key_exprs in sorted(grants.allowed.items()):
            rule_id = f"{identity}-{flow}-{message}"
            rules.append(
                {
                    "id": rule_id,
                    "messages": [message],
                    "flows": [flow],
                    "permission": "allow",
                    "key_exprs": sorted(set(key_exprs)),
                }
            )
            rule_ids.append(rule_id)
        if rule_ids:
            policies.append({"id": identity, "rules": rule_ids, "subjects": [identity]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def robot_put_limits(swarm: str) -> list[dict[str, Any]]:
    """The `low_pass_filter` section: the size limit of each key the robots put on, applied
    where the message enters the router (module docstring, "Sizes")."""
    keys = SwarmKeys(swarm)
    limits = {
        "robot-act-and-frames": ([keys.act_all, keys.radio_tx_all], ACT_AND_FRAME_BYTES_MAX),
        "robot-telemetry": ([keys.telemetry_all], TELEMETRY_BYTES_MAX),
    }
    return [
        {
            "id": limit_id,
            "flows": ["ingress"],
            "messages": list(PUBLISH),
            "key_exprs": key_exprs,
            "size_limit": size_limit,
        }
        for limit_id, (key_exprs, size_limit) in limits.items()
    ]


def tls_link(tls: TlsFiles) -> dict[str, Any]:
    """The router's `transport/link/tls` section: its certificate and key for `tls/`
    listeners, the swarm's CA for links it opens itself. Clients show no certificate (no
    mTLS): they log in with user and password, as on `tcp/`."""
    return {
        "listen_certificate": str(tls.router_certificate.resolve()),
        "listen_private_key": str(tls.router_private_key.resolve()),
        "root_ca_certificate": str(tls.ca_certificate.resolve()),
    }


@dataclass(frozen=True)
class CertificateNames:
    """Who a certificate names: its subject's common name and its subjectAltName entries."""

    common_name: str
    ip_addresses: frozenset[str]
    dns_names: frozenset[str]

    def covers(self, host: str) -> bool:
        """Whether a client reaching the router at `host` accepts this certificate."""
        try:
            return str(ipaddress.ip_address(host)) in self.ip_addresses
        except ValueError:
            return host.lower() in self.dns_names


def certificate_names(certificate: Path) -> CertificateNames:
    """The names in a PEM certificate (read by `openssl x509`); TlsError when it cannot be
    read or has no common name."""
    try:
        result = subprocess.run(
            [find_openssl(), "x509", "-in", str(certificate), "-noout", "-nameopt", "RFC2253"]
            + ["-subject", "-ext", "subjectAltName"],
            capture_output=True,
            text=True,
            timeout=OPENSSL_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise TlsError(f"cannot read {certificate}: {exc}") from None
    if result.returncode != 0:
        raise TlsError(f"{certificate} is not a certificate `openssl x509` reads")
    common_name = ""
    ips: set[str] = set()
    dns: set[str] = set()
    for line in result.stdout.splitlines():
        line = line.strip()
        if line.startswith("subject="):
            for part in line.removeprefix("subject=").split(","):
                key, _, value = part.strip().partition("=")
                if key == "CN":
                    common_name = value
        for entry in line.split(","):
            kind, _, value = entry.strip().partition(":")
            if kind == "IP Address" and value:
                ips.add(str(ipaddress.ip_address(value.strip())))
            elif kind == "DNS" and value:
                dns.add(value.strip().lower())
    if not common_name:
        raise TlsError(f"{certificate} names no common name (CN)")
    return CertificateNames(common_name, frozenset(ips), frozenset(dns))


def endpoint_host(endpoint: str) -> str:
    """HOST of `proto/HOST:PORT[?options]` (an IPv6 address without its brackets)."""
    address = endpoint.split("/", 1)[-1].split("?", 1)[0]
    return address.rsplit(":", 1)[0].strip("[]")


def check_router_links(
    connect: Sequence[str], accept: Sequence[str], tls: TlsFiles | None
) -> CertificateNames | None:
    """The router certificate's names when this router has links to other hosts (`connect`:
    the hub's endpoints; `accept`: where the hub takes other hosts' routers), after checking
    that every such endpoint is `tls/`, that there is a certificate, and that it names each
    host a link reaches the hub at; TlsError saying what to do otherwise."""
    links = [*connect, *accept]
    if not links:
        return None
    plain = [endpoint for endpoint in links if not endpoint.startswith("tls/")]
    if plain:
        raise TlsError(
            f"router links between hosts run over TLS, not {', '.join(plain)}: give "
            "tls/HOST:PORT (HOST: the world host's address in its router certificate)"
        )
    if tls is None:
        raise TlsError(
            "router links between hosts need the swarm's CA and router certificate: make them "
            "with `swarm credentials DIR --tls --tls-host HOST` (HOST: the world host's "
            "address) and give every host a copy of DIR"
        )
    names = certificate_names(tls.router_certificate)
    for endpoint in links:
        host = endpoint_host(endpoint)
        unspecified = host in ("0.0.0.0", "::")  # a listener on every interface
        if not unspecified and not names.covers(host):
            raise TlsError(
                f"{endpoint}: the router certificate {tls.router_certificate} does not name "
                f"{host}, so the other hosts' routers would refuse it; make one that does "
                f"with `swarm credentials DIR --tls --rotate --tls-host {host}`"
            )
    return names


def router_config_document(
    credentials: CredentialSet,
    users_file: Path,
    listen: Sequence[str],
    tls: TlsFiles | None = None,
    connect: Sequence[str] = (),
    accept_routers: bool = False,
) -> dict[str, Any]:
    """The whole router config of a run (what configs/zenoh/router.json5 sets, plus login and
    access control, and with `tls` the certificate of its `tls/` endpoints); usable by
    `swarm router --config` and by a stock `zenohd -c`.

    A swarm over hosts (module docstring): `accept_routers` makes the hub, whose `tls/` listen
    endpoints take the other hosts' routers; `connect` (the hub's `tls/` endpoints) makes
    another host's router, linked to the hub. TlsError for a `tls/` endpoint without `tls`,
    or a link that is not TLS or reaches a host the router certificate does not name."""
    if tls is None and any(endpoint.startswith("tls/") for endpoint in listen):
        raise TlsError(
            "a tls/ listen endpoint needs the router's certificate: make one with "
            "`swarm credentials DIR --tls`"
        )
    accepting = [e for e in listen if e.startswith("tls/")] if accept_routers else []
    if accept_routers and not accepting:
        raise TlsError("a router that takes other hosts' routers needs a tls/ listen endpoint")
    names = check_router_links(connect, accepting, tls)
    router_password = credentials.passwords[ROUTER].get_secret_value()
    transport: dict[str, Any] = {
        "auth": {
            "usrpwd": {
                "user": ROUTER,
                "password": router_password,
                "dictionary_file": str(users_file),
            }
        }
    }
    link: dict[str, Any] = {"rx": {"max_message_size": MESSAGE_BYTES_MAX}}
    if tls is not None:
        link["tls"] = tls_link(tls)
    if names is not None:
        link["tx"] = {"lease": ROUTER_LINK_LEASE_MS}
    transport["link"] = link
    transport["unicast"] = {
        "accept_pending": ROUTER_ACCEPT_PENDING,
        "accept_timeout": ROUTER_ACCEPT_TIMEOUT_MS,
    }
    document: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
    }
    if connect:
        document["connect"] = {
            "endpoints": list(connect),
            "timeout_ms": -1,
            "exit_on_failure": False,
            "retry": dict(ROUTER_LINK_RETRY),
        }
    document.update(
        {
            "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
            "transport": transport,
            "low_pass_filter": robot_put_limits(credentials.swarm),
            "access_control": access_control(
                credentials.swarm,
                credentials.robots,
                accept_routers,
                names.common_name if connect and names is not None else None,
            ),
        }
    )
    return document


def write_router_config(
    directory: Path,
    credentials: CredentialSet,
    listen: Sequence[str],
    tls: TlsFiles | None = None,
    connect: Sequence[str] = (),
    accept_routers: bool = False,
    path: Path | None = None,
) -> Path:
    """Write the run's router config (mode 0600: it holds the router's password) beside the
    credentials written by `write_credential_set` in `directory` (or at `path`); returns its
    path."""
    path = directory / ROUTER_CONFIG_FILE if path is None else path
    users_file = (directory / ROUTER_USERS_FILE).resolve()
    document = router_config_document(credentials, users_file, listen, tls, connect, accept_routers)
    text = "// Generated for one run by `swarm up`; see services/router/access.py.\n"
    write_private_file(path, (text + json.dumps(document, indent=2) + "\n").encode("utf-8"))
    return path

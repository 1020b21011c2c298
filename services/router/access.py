"""The router's per-run config: who may log in, and what each identity may do (DESIGN.md §7.1).

`router_config_document` builds, for one run, the whole router config (the settings of
configs/zenoh/router.json5, plus):

* `transport/auth/usrpwd`: every client must log in with a user and password listed in the
  run's `router-users.txt` (swarm_config/credentials.py); no login, no session;
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

Robots and the world may also receive every subscriber declaration of the swarm
(`declare_subscriber` egress on `swarm/<swarm>/**`): a Zenoh publisher sends only when it
knows of a matching subscriber, and the subscriptions it must hear of are wider than its own
key (the world subscribes to `wire/*/act`), which an ACL rule for `wire/robot1/act` does not
cover. What they learn is which key expressions someone subscribes to, never data.
"""

from __future__ import annotations

import json
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
from swarm_config.tls import TlsError, TlsFiles

ROUTER_CONFIG_FILE = "router.json5"
"""The generated router config, beside the credentials (it names the user file)."""

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


def identity_grants(swarm: str, robots: Sequence[str]) -> dict[str, Grants]:
    """What each identity of a run of `robots` on `swarm` may do (the table above)."""
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
    launcher = grants[LAUNCHER] = Grants()
    _server(launcher, keys.admin(LAUNCHER, "*"))
    _token(launcher, keys.alive(LAUNCHER, LAUNCHER))
    dashboard = grants[DASHBOARD] = Grants()
    _subscriber(dashboard, keys.truth, keys.telemetry_all)
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
    return grants


def access_control(swarm: str, robots: Sequence[str]) -> dict[str, Any]:
    """The `access_control` section: default deny, one subject and its rules per identity."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for identity, grants in identity_grants(swarm, robots).items():
        subjects.append({"id": identity, "usernames": [identity]})
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


def tls_link(tls: TlsFiles) -> dict[str, Any]:
    """The router's `transport/link/tls` section: its certificate and key for `tls/`
    listeners, the swarm's CA for links it opens itself. Clients show no certificate (no
    mTLS): they log in with user and password, as on `tcp/`."""
    return {
        "listen_certificate": str(tls.router_certificate.resolve()),
        "listen_private_key": str(tls.router_private_key.resolve()),
        "root_ca_certificate": str(tls.ca_certificate.resolve()),
    }


def router_config_document(
    credentials: CredentialSet,
    users_file: Path,
    listen: Sequence[str],
    tls: TlsFiles | None = None,
) -> dict[str, Any]:
    """The whole router config of a run (what configs/zenoh/router.json5 sets, plus login and
    access control, and with `tls` the certificate of its `tls/` endpoints); usable by
    `swarm router --config` and by a stock `zenohd -c`. TlsError for a `tls/` endpoint
    without `tls`."""
    if tls is None and any(endpoint.startswith("tls/") for endpoint in listen):
        raise TlsError(
            "a tls/ listen endpoint needs the router's certificate: make one with "
            "`swarm credentials DIR --tls`"
        )
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
    if tls is not None:
        transport["link"] = {"tls": tls_link(tls)}
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
        "transport": transport,
        "access_control": access_control(credentials.swarm, credentials.robots),
    }


def write_router_config(
    directory: Path,
    credentials: CredentialSet,
    listen: Sequence[str],
    tls: TlsFiles | None = None,
) -> Path:
    """Write the run's router config (mode 0600: it holds the router's password) beside the
    credentials written by `write_credential_set`; returns its path."""
    path = directory / ROUTER_CONFIG_FILE
    document = router_config_document(
        credentials, (directory / ROUTER_USERS_FILE).resolve(), listen, tls
    )
    text = "// Generated for one run by `swarm up`; see services/router/access.py.\n"
    write_private_file(path, (text + json.dumps(document, indent=2) + "\n").encode("utf-8"))
    return path

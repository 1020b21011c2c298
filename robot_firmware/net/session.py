"""One place that turns command-line and environment settings into a Zenoh session.

Every process of the swarm is a client of the router (DESIGN.md §2): `client_config` starts
from `configs/zenoh/client.json5` (wait for the router, retry, short lease) and overrides the
endpoints; `router_config` does the same for the router from `configs/zenoh/router.json5`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import zenoh

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "zenoh"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def _load(path: Path | None, default_name: str) -> zenoh.Config:
    source = path if path is not None else CONFIG_DIR / default_name
    if source.exists():
        return zenoh.Config.from_file(str(source))
    return zenoh.Config()


def client_config(
    connect: Sequence[str] = (DEFAULT_ENDPOINT,), config_file: Path | None = None
) -> zenoh.Config:
    config = _load(config_file, "client.json5")
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return config


def router_config(
    listen: Sequence[str] | None = None, config_file: Path | None = None
) -> zenoh.Config:
    config = _load(config_file, "router.json5")
    config.insert_json5("mode", json.dumps("router"))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return config


def open_client(connect: Sequence[str], config_file: Path | None = None) -> zenoh.Session:
    """A client session; with the default config it waits for the router to come up."""
    zenoh.init_log_from_env_or("error")
    return zenoh.open(client_config(connect, config_file))


def split_endpoints(text: str) -> list[str]:
    """'tcp/a:7447, tcp/b:7447' -> ['tcp/a:7447', 'tcp/b:7447']."""
    return [part.strip() for part in text.split(",") if part.strip()]

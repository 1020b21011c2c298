"""Run a Zenoh router from a json5 config until SIGTERM, SIGHUP or Ctrl-C.

The same config file works with a stock `zenohd -c configs/zenoh/router.json5`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from robot_firmware.net.session import (
    ROUTER_ZENOH_RUNTIME,
    open_session,
    router_config,
    zenoh_runtime_while_opening,
)
from services.stop_signals import stop_on_signals, wait_for_stop
from swarm_config.settings import SettingsError

log = logging.getLogger("swarm.router")


def run_router(listen: Sequence[str] | None, config_file: Path | None) -> int:
    zenoh.init_log_from_env_or("error")
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        config = router_config(listen, config_file)
    except (zenoh.ZError, OSError, SettingsError) as exc:  # a user's file or endpoint: one line
        log.error("cannot use the router config %s: %s", config_file or "(default)", exc)
        return 2
    try:
        with zenoh_runtime_while_opening(ROUTER_ZENOH_RUNTIME):
            session = open_session(config)
    except zenoh.ZError as exc:  # e.g. the port is taken: say so in one line, no traceback
        where = ", ".join(listen) if listen else "the config endpoints"
        log.error("cannot start the router on %s: %s", where, exc)
        return 1
    with session:
        log.info("router up, zid %s", session.info.zid())
        print(
            f"router listening on {', '.join(listen) if listen else 'the config endpoints'}",
            flush=True,
        )
        wait_for_stop(stop)
    return 0

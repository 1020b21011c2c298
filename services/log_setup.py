"""The log set-up of every `swarm` process: one line per record, at `$SWARM_LOG_LEVEL`.

The launcher's children (router, world, robots, dashboard) inherit the variable, so a level
that is not one stops `swarm up` with the variable named, before anything starts, instead of
a traceback from the logging module.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping

LOG_LEVEL_ENV = "SWARM_LOG_LEVEL"
DEFAULT_LOG_LEVEL = "INFO"
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


class LogLevelError(ValueError):
    """`$SWARM_LOG_LEVEL` names no level; the message says which ones there are."""


def log_level_from(environ: Mapping[str, str]) -> str:
    """The level `environ` asks for (any case; unset or empty: INFO)."""
    given = environ.get(LOG_LEVEL_ENV, "").strip()
    if not given:
        return DEFAULT_LOG_LEVEL
    if given.upper() not in LOG_LEVELS:
        raise LogLevelError(
            f"${LOG_LEVEL_ENV}={given!r} is not a log level; use one of {', '.join(LOG_LEVELS)}"
        )
    return given.upper()


def set_up_logging(environ: Mapping[str, str] = os.environ) -> None:
    """Log to stderr at the level of `$SWARM_LOG_LEVEL`; LogLevelError when it names none."""
    logging.basicConfig(level=log_level_from(environ), format=LOG_FORMAT)

"""Files a running world cannot write: counted, logged without flooding the log, and survived.

The world writes three kinds of file while a run goes on: its periodic `summary.json`, its
checkpoints and `events.jsonl`.  A full disk, a quota or a run folder that became read-only
makes those writes fail; the world must keep stepping all the same (every robot stops when
the world does), so each kind keeps a `WriteFailures`:

* the first failure of a streak is logged as an error, with the reason;
* while the writes keep failing, one line every `repeat_every_s` says how many failed since;
* the first write that succeeds again says so, with the count of the streak.

The counts per kind go into `admin/world/status` (`write_failures`) and, when any write
failed, into the final summary.  The files themselves stay whole: every write is atomic
(swarm_config/atomic_files.py), so a failed one leaves the previous file as it was.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

EXIT_SUMMARY_NOT_WRITTEN = 3
"""The world's exit status when its run ended but the final summary.json could not be written
(a full disk, a read-only run folder): the launcher says so instead of restarting the world."""

REPEAT_EVERY_S = 60.0
"""While writes of one kind keep failing, a log line at most this often (wall seconds)."""


class WriteFailures:
    """The failures of one kind of write (`what`, e.g. "checkpoint"), reported to `logger`."""

    def __init__(
        self,
        what: str,
        logger: logging.Logger,
        repeat_every_s: float = REPEAT_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.what = what
        self.failures = 0
        """Every failed write of this kind since the process started."""
        self._log = logger
        self._repeat_every_s = repeat_every_s
        self._clock = clock
        self._streak = 0
        self._reported_streak = 0
        self._reported_at_s = 0.0

    @property
    def failing(self) -> bool:
        """True from a failed write until the next one that succeeds."""
        return self._streak > 0

    def failed(self, error: OSError) -> None:
        """A write of this kind failed with `error`: count it, log it if it is time to."""
        self.failures += 1
        self._streak += 1
        now_s = self._clock()
        if self._streak == 1:
            self._log.error("%s not written: %s; the run goes on", self.what, error)
        elif now_s - self._reported_at_s >= self._repeat_every_s:
            self._log.error(
                "%s still not written: %d more failures since (%s)",
                self.what,
                self._streak - self._reported_streak,
                error,
            )
        else:
            return
        self._reported_at_s = now_s
        self._reported_streak = self._streak

    def succeeded(self) -> None:
        """A write of this kind went through: end the streak, saying so if there was one."""
        if self._streak:
            self._log.warning("%s written again after %d failures", self.what, self._streak)
        self._streak = 0
        self._reported_streak = 0

"""Whether the robot's sonar ring still hears: a pure check of each sweep (DESIGN.md §7).

The obstacle term of the avoidance (eqs. 22-25) and the approach guard see obstacles only
through the sonar.  A ring that has gone deaf (a transducer cable, the echo input of the
ultrasound IP; the `sonar_no_echo` register fault) reads "no echo" on every beam, which is also
what open space reads, so silence alone proves nothing.  A peer does: the ring's beams cover
the whole circle, so a peer body whose gap to this robot is well inside the sonar's range lies
in some beam and must echo there.  So a sweep in which no beam hears anything while a peer
known from the radio is nearer than `reach_m` is *silent against the evidence*; after
`failing_sweeps` of those in a row the ring is taken as failed (at 20 Hz, 0.15 s), and it is
well again at the first sweep that hears anything.  A robot alone in open space, or one whose
peers are all out of reach, keeps its verdict: no evidence either way.

While the ring is failed the firmware holds the robot still (robot_firmware/firmware.py): it
cannot see obstacles, and the other robots, which know where it is from its frames, go round
it.  When the ring hears again it drives on from fresh control state.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FAILING_SWEEPS = 3
"""Silent sweeps against the evidence, in a row, before the ring is taken as failed."""
REACH_MARGIN_M = 0.5
"""How far inside the sonar's range a peer must be to count as evidence (pose errors, noise)."""


@dataclass
class SonarHealth:
    """The verdict on one robot's sonar ring, sweep by sweep (module docstring)."""

    reach_m: float
    """A peer whose body-to-body gap is at most this must echo on some beam."""
    failing_sweeps: int = FAILING_SWEEPS
    failed: bool = field(init=False, default=False)
    silent_sweeps: int = field(init=False, default=0)
    """Silent sweeps against the evidence since the ring last heard anything."""
    failures: int = field(init=False, default=0)
    """How often the ring was taken as failed since boot."""

    @classmethod
    def for_range(cls, max_range_m: float) -> SonarHealth:
        """The check for a ring that reads up to `max_range_m` (gaps beyond read no echo)."""
        return cls(reach_m=max(max_range_m - REACH_MARGIN_M, 0.0))

    def sweep(self, ranges_m: NDArray[np.float64], peer_gaps_m: Iterable[float]) -> bool:
        """One fresh sweep (inf: no echo on that beam), and the gaps to the peers known now;
        returns whether the ring is failed."""
        if bool(np.any(np.isfinite(ranges_m))):
            self.silent_sweeps = 0
            self.failed = False
        elif any(gap <= self.reach_m for gap in peer_gaps_m):
            self.silent_sweeps += 1
            if self.silent_sweeps >= self.failing_sweeps and not self.failed:
                self.failed = True
                self.failures += 1
        return self.failed

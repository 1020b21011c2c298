"""What the fuzz tests fed each target and what became of it, for the session's summary table.

Each target (a decoder, an admin verb, a file loader) counts its generated inputs by outcome:
`accepted`, or the named reason it was refused.  `tests/fuzz/conftest.py` prints the table at
the end of the session (pytest captures a passing test's output, so a test cannot print it).
"""

from __future__ import annotations

import enum
from collections import Counter
from dataclasses import dataclass, field

ACCEPTED = "accepted"


@dataclass
class FuzzLedger:
    outcomes: dict[str, Counter[str]] = field(default_factory=dict)
    """target -> outcome (`accepted` or a refusal reason) -> inputs."""

    def record(self, target: str, outcome: object) -> None:
        """Count one input of `target`: `outcome` is ACCEPTED, a reason enum or its name."""
        name = outcome.value if isinstance(outcome, enum.Enum) else str(outcome)
        self.outcomes.setdefault(target, Counter())[name] += 1

    def inputs(self, target: str) -> int:
        return sum(self.outcomes.get(target, Counter()).values())

    def rejected(self, target: str) -> int:
        counts = self.outcomes.get(target, Counter())
        return sum(n for outcome, n in counts.items() if outcome != ACCEPTED)

    def table(self) -> list[str]:
        """One block per target: inputs, accepted, then each refusal reason, most common first."""
        lines = [f"{'target':<34} {'inputs':>8} {'accepted':>9} {'rejected':>9}  reasons"]
        for target in sorted(self.outcomes):
            counts = self.outcomes[target]
            reasons = sorted(
                ((r, n) for r, n in counts.items() if r != ACCEPTED), key=lambda item: -item[1]
            )
            lines.append(
                f"{target:<34} {self.inputs(target):>8} {counts[ACCEPTED]:>9} "
                f"{self.rejected(target):>9}  " + (", ".join(f"{r} {n}" for r, n in reasons) or "-")
            )
        return lines


LEDGER = FuzzLedger()
"""The session's ledger: every fuzz test records into it."""

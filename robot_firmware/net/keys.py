"""The Zenoh key space of a swarm (DESIGN.md §3): every key is built here and nowhere else.

swarm/<swarm>/wire/<robot>/act      fabric -> world   PWM pins, watchdog state
swarm/<swarm>/wire/<robot>/sense    world -> fabric   encoders, sonar echoes, fix
swarm/<swarm>/radio/tx/<robot>      robot -> world    one broadcast frame (opaque bytes)
swarm/<swarm>/radio/rx/<robot>      world -> robot    frames delivered to that robot
swarm/<swarm>/clock                 world -> all      simulation time, lockstep ticks
swarm/<swarm>/truth                 world -> viewers  poses, metrics
swarm/<swarm>/events                world -> viewers  faults and their consequences (RunEvent)
swarm/<swarm>/telemetry/<robot>     robot -> viewers  estimate, desired pose, gains
swarm/<swarm>/alive/<role>/<name>   liveliness token of each live process
swarm/<swarm>/admin/<target>/<verb> queryables (status, regs, net, params)
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")


def check_name(kind: str, name: str) -> str:
    """A swarm or robot name usable as one key chunk; ValueError otherwise."""
    if not _NAME.match(name):
        # A name of thousands of characters is named by its start and length, not echoed whole.
        shown = repr(name) if len(name) <= 40 else f"{name[:32]!r}... ({len(name)} characters)"
        raise ValueError(
            f"{kind} name {shown} must be 1-32 characters: a lowercase letter, then lowercase "
            "letters, digits, '-' or '_'"
        )
    return name


@dataclass(frozen=True)
class SwarmKeys:
    swarm: str

    def __post_init__(self) -> None:
        check_name("swarm", self.swarm)

    @property
    def root(self) -> str:
        return f"swarm/{self.swarm}"

    @property
    def everything(self) -> str:
        """Every key of the swarm (access control: what the operator may read)."""
        return f"{self.root}/**"

    def everything_under(self, chunk: str) -> str:
        """Every key under `swarm/<swarm>/<chunk>/`, e.g. every admin verb or liveliness token."""
        return f"{self.root}/{chunk}/**"

    def act(self, robot: str) -> str:
        return f"{self.root}/wire/{robot}/act"

    def sense(self, robot: str) -> str:
        return f"{self.root}/wire/{robot}/sense"

    def radio_tx(self, robot: str) -> str:
        return f"{self.root}/radio/tx/{robot}"

    def radio_rx(self, robot: str) -> str:
        return f"{self.root}/radio/rx/{robot}"

    @property
    def radio_tx_all(self) -> str:
        return f"{self.root}/radio/tx/*"

    @property
    def act_all(self) -> str:
        return f"{self.root}/wire/*/act"

    @property
    def clock(self) -> str:
        return f"{self.root}/clock"

    @property
    def truth(self) -> str:
        return f"{self.root}/truth"

    def events(self) -> str:
        """The run's events (swarm_config/faults.py `RunEvent`), as the world records them."""
        return f"{self.root}/events"

    def telemetry(self, robot: str) -> str:
        return f"{self.root}/telemetry/{robot}"

    @property
    def telemetry_all(self) -> str:
        return f"{self.root}/telemetry/*"

    def alive(self, role: str, name: str) -> str:
        return f"{self.root}/alive/{role}/{name}"

    def alive_all(self, role: str = "*") -> str:
        return f"{self.root}/alive/{role}/*"

    def admin(self, target: str, verb: str) -> str:
        return f"{self.root}/admin/{target}/{verb}"

    @staticmethod
    def last_chunk(key: str) -> str:
        return key.rsplit("/", 1)[-1]

    @staticmethod
    def chunk(key: str, index: int) -> str:
        return key.split("/")[index]

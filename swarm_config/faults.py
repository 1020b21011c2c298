"""Faults a user can inject into a running swarm, the `faults:` schedule of a scenario, and the
events a run records (DESIGN.md §7, robustness semantics).

One model per fault, all in one union discriminated by `fault`, so that `swarm fault`, the
world's `fault` admin verb, a robot's `fault` admin verb and a scenario's `faults:` schedule read
the same JSON and refuse the same mistakes with the same message.  Three kinds:

- **process** faults act on an OS process of the swarm (a robot, `world`, `router`,
  `dashboard`): `kill` (SIGKILL, a power cut), `stop` / `cont` (SIGSTOP / SIGCONT, a frozen
  board) and `restart`;
- **network** faults change the radio medium that the world emulates: `net` sets loss, delay,
  jitter or a burst model on every link, on the links of one robot or on one link; `partition`
  cuts a set of robots off from the rest; `heal` undoes every network fault;
- **register** faults act inside one robot's FPGA model, below its firmware: a stuck encoder
  count or bit, a sonar with no echo, a stuck or saturated PWM, a cut positioning fix, a watchdog
  forced to expire, a control tick slowed by some milliseconds (CPU overload);
  `clear_registers` undoes them.

Every fault injected, and every consequence seen (a robot down or back, a leader change, a world
resumed from a checkpoint), is a `RunEvent` with its simulation time, one JSON line each in the
run's `events.jsonl`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from swarm_config.radio import BurstLoss
from swarm_config.settings import boolean_number_problems

PROCESS_ROLES = ("world", "router", "dashboard")
"""Process names other than robots' that process faults accept."""

ROBOT_NAME_PATTERN = r"^[a-z][a-z0-9_-]{0,31}$"
WHEELS = 4
"""The four-wheel omnidirectional body: wheels 0-3 (QEP and PWM channels)."""


class _Fault(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @property
    def kind(self) -> Literal["process", "network", "register"]:
        raise NotImplementedError


# --- process faults ------------------------------------------------------------------------


class _ProcessFault(_Fault):
    process: str = Field(pattern=ROBOT_NAME_PATTERN)
    """A robot's name, or `world`, `router`, `dashboard`."""

    @property
    def kind(self) -> Literal["process"]:
        return "process"


class KillFault(_ProcessFault):
    """SIGKILL the process: a power cut. It stays down until a `restart`."""

    fault: Literal["kill"]


class StopFault(_ProcessFault):
    """SIGSTOP the process: a frozen board that keeps its state until `cont`."""

    fault: Literal["stop"]


class ContFault(_ProcessFault):
    """SIGCONT a stopped process."""

    fault: Literal["cont"]


class RestartFault(_ProcessFault):
    """Start the process again (kill it first if it runs)."""

    fault: Literal["restart"]


# --- network faults ------------------------------------------------------------------------


class _NetworkFault(_Fault):
    @property
    def kind(self) -> Literal["network"]:
        return "network"


class NetFault(_NetworkFault):
    """Loss, delay, jitter or bursts on every link (no `robot`, no `link`), on every link to or
    from one robot (`robot`), or on one link in both directions (`link`).  Fields not given keep
    the value of the scenario's profile."""

    fault: Literal["net"]
    robot: str | None = Field(default=None, pattern=ROBOT_NAME_PATTERN)
    link: tuple[str, str] | None = None
    latency_ms: float | None = Field(default=None, ge=0.0, le=10_000.0)
    jitter_ms: float | None = Field(default=None, ge=0.0, le=10_000.0)
    loss: float | None = Field(default=None, ge=0.0, le=1.0)
    burst: BurstLoss | None = None

    @model_validator(mode="after")
    def _one_scope_and_something_to_set(self) -> NetFault:
        if self.robot is not None and self.link is not None:
            raise ValueError("give 'robot' or 'link', not both")
        if self.link is not None and self.link[0] == self.link[1]:
            raise ValueError("a link joins two different robots")
        if all(v is None for v in (self.latency_ms, self.jitter_ms, self.loss, self.burst)):
            raise ValueError("nothing to set: give latency_ms, jitter_ms, loss or burst")
        if self.burst is not None and self.loss is not None:
            raise ValueError("give either 'loss' (independent) or 'burst' (Gilbert-Elliott)")
        return self


class PartitionFault(_NetworkFault):
    """Cut `robots` off from the rest: no frame crosses between the two sides until `heal`."""

    fault: Literal["partition"]
    robots: tuple[str, ...] = Field(min_length=1)

    @model_validator(mode="after")
    def _each_robot_once(self) -> PartitionFault:
        repeated = sorted({name for name in self.robots if self.robots.count(name) > 1})
        if repeated:
            raise ValueError(f"{repeated[0]!r} is named twice")
        return self


class HealFault(_NetworkFault):
    """Undo every network fault: partitions gone, every link back to the scenario's profile."""

    fault: Literal["heal"]


# --- register faults -----------------------------------------------------------------------


class _RegisterFault(_Fault):
    robot: str = Field(pattern=ROBOT_NAME_PATTERN)

    @property
    def kind(self) -> Literal["register"]:
        return "register"


class EncoderStuckFault(_RegisterFault):
    """The QEP count of one wheel stops changing (the encoder's lines are cut)."""

    fault: Literal["encoder_stuck"]
    wheel: int = Field(ge=0, lt=WHEELS)


class EncoderBitStuckFault(_RegisterFault):
    """One bit of one wheel's QEP count register reads `value` whatever the count."""

    fault: Literal["encoder_bit_stuck"]
    wheel: int = Field(ge=0, lt=WHEELS)
    bit: int = Field(ge=0, lt=32)
    value: Literal[0, 1]


class SonarNoEchoFault(_RegisterFault):
    """The ultrasound IP never sees an echo: every range reads as 'nothing in range'."""

    fault: Literal["sonar_no_echo"]


class PwmStuckFault(_RegisterFault):
    """One wheel's PWM output holds `duty` (signed, -1..1) whatever the firmware writes."""

    fault: Literal["pwm_stuck"]
    wheel: int = Field(ge=0, lt=WHEELS)
    duty: float = Field(ge=-1.0, le=1.0)


class PwmSaturatedFault(_RegisterFault):
    """One wheel's PWM output is driven to full duty in the direction `sign`."""

    fault: Literal["pwm_saturated"]
    wheel: int = Field(ge=0, lt=WHEELS)
    sign: Literal[-1, 1] = 1


class FixCutFault(_RegisterFault):
    """The positioning IP gets no new fix (GNSS/UWB outage): the robot must dead-reckon."""

    fault: Literal["fix_cut"]


class WatchdogExpireFault(_RegisterFault):
    """The watchdog IP expires now, as if the firmware had stopped kicking it."""

    fault: Literal["watchdog_expire"]


class TickSlowFault(_RegisterFault):
    """Every control tick of the robot takes `extra_ms` longer (CPU overload on the board)."""

    fault: Literal["tick_slow"]
    extra_ms: float = Field(gt=0.0, le=10_000.0)


class ClearRegistersFault(_RegisterFault):
    """Undo every register fault of the robot."""

    fault: Literal["clear_registers"]


Fault = Annotated[
    KillFault
    | StopFault
    | ContFault
    | RestartFault
    | NetFault
    | PartitionFault
    | HealFault
    | EncoderStuckFault
    | EncoderBitStuckFault
    | SonarNoEchoFault
    | PwmStuckFault
    | PwmSaturatedFault
    | FixCutFault
    | WatchdogExpireFault
    | TickSlowFault
    | ClearRegistersFault,
    Field(discriminator="fault"),
]
"""Any fault, read from JSON or YAML by its `fault` field."""

FAULT_ADAPTER: TypeAdapter[Fault] = TypeAdapter(Fault)
"""`FAULT_ADAPTER.validate_python(obj)` / `.validate_json(bytes)`: one fault, or a
`ValidationError` that names the field."""


def fault_name(model: type[BaseModel]) -> str:
    """The `fault` value of one fault model."""
    (name,) = get_args(model.model_fields["fault"].annotation)
    return str(name)


FAULT_MODELS: dict[str, type[BaseModel]] = {
    fault_name(model): model
    for model in get_args(get_args(Fault)[0])  # Annotated[Union[...], Field] -> the models
}
"""Every fault's model by its `fault` value."""


def fault_boolean_problems(data: object) -> list[str]:
    """'field: a number, not true' for every number field of a fault given as a mapping (JSON,
    `swarm fault --json`, the world's `fault` verb) that is given a boolean, which pydantic
    would take for 1 or 0 (swarm_config/settings.py `boolean_number_problems`)."""
    if not isinstance(data, Mapping):
        return []
    model = FAULT_MODELS.get(str(data.get("fault")))
    return [] if model is None else boolean_number_problems(model, data)


REGISTER_FAULTS = (
    EncoderStuckFault,
    EncoderBitStuckFault,
    SonarNoEchoFault,
    PwmStuckFault,
    PwmSaturatedFault,
    FixCutFault,
    WatchdogExpireFault,
    TickSlowFault,
    ClearRegistersFault,
)
RegisterFault = (
    EncoderStuckFault
    | EncoderBitStuckFault
    | SonarNoEchoFault
    | PwmStuckFault
    | PwmSaturatedFault
    | FixCutFault
    | WatchdogExpireFault
    | TickSlowFault
    | ClearRegistersFault
)
REGISTER_FAULT_ADAPTER: TypeAdapter[RegisterFault] = TypeAdapter(
    Annotated[RegisterFault, Field(discriminator="fault")]
)
"""What a robot's `fault` admin verb accepts."""


FAULT_NAMES = (
    "kill",
    "stop",
    "cont",
    "restart",
    "net",
    "partition",
    "heal",
    "encoder_stuck",
    "encoder_bit_stuck",
    "sonar_no_echo",
    "pwm_stuck",
    "pwm_saturated",
    "fix_cut",
    "watchdog_expire",
    "tick_slow",
    "clear_registers",
)
"""Every fault's `fault` value, in the order of the union."""


def swarm_fault_problem(fault: Fault, robots: Sequence[str]) -> str | None:
    """What makes `fault` meaningless in a swarm of `robots` beyond naming one outside it
    (which the callers refuse with their own reasons), else None: a partition of every robot
    cuts nobody off from anybody."""
    if isinstance(fault, PartitionFault) and set(robots) <= set(fault.robots):
        return (
            f"a partition of every robot ({', '.join(robots)}) cuts nobody off: name the robots "
            "of one side"
        )
    return None


def fault_subjects(fault: Fault) -> tuple[str, ...]:
    """The names the fault is about (robots or processes), for checking against a swarm."""
    match fault:
        case KillFault() | StopFault() | ContFault() | RestartFault():
            return (fault.process,)
        case NetFault():
            if fault.link is not None:
                return fault.link
            return () if fault.robot is None else (fault.robot,)
        case PartitionFault():
            return fault.robots
        case HealFault():
            return ()
        case _:
            return (fault.robot,)


class ScheduledFault(BaseModel):
    """One entry of a scenario's `faults:` schedule: at simulation time `at_s`, inject `fault`."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    at_s: float = Field(ge=0.0)
    fault: Fault


# --- events --------------------------------------------------------------------------------

EventKind = Literal[
    "fault_injected",
    "fault_refused",
    "robot_down",
    "robot_up",
    "leader_change",
    "world_resumed",
    "collision",
]


class RunEvent(BaseModel):
    """One line of `events.jsonl`: what happened at simulation time `t_s`.

    `fault_injected` carries the fault (its JSON) in `detail["fault"]` and where it came from in
    `detail["source"]` (`schedule` or `admin`); `fault_refused` carries the reason; `robot_down`
    and `robot_up` name the robot in `subject`; `leader_change` names the new leader in `subject`
    and its term in `detail["term"]`; `world_resumed` gives the checkpoint's time."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    t_s: float
    kind: EventKind
    subject: str | None = None
    detail: dict[str, Any] = Field(default_factory=dict)

"""Every JSON message of the swarm, as pydantic models: one module, imported by producers and
consumers alike (DESIGN.md §3: configs and admin payloads are pydantic models).

Binary wire formats (sense, act, clock, radio frames) live in `wire.py` and `frames.py`; the
JSON ones are here:

| key                                   | producer  | model                                  |
|---------------------------------------|-----------|----------------------------------------|
| `truth`                               | world     | `TruthMessage`                         |
| `telemetry/<robot>`                   | robot     | `TelemetryMessage`                     |
| `admin/<robot>/status`                | robot     | `RobotStatusReply`                     |
| `admin/<robot>/regs`                  | robot     | `RegsRequest` -> `RegsReply`           |
| `admin/<robot>/params`                | robot     | fuzzy parameter file -> `ParamsReply`  |
| `admin/<robot>/fault`                 | robot     | one register fault (or nothing) ->     |
|                                       |           | `RegisterFaultsReply`                  |
| `admin/world/status`                  | world     | `WorldStatusReply`                     |
| `admin/world/net`                     | world     | `NetProfileRequest` or a partial       |
|                                       |           | `LinkProfile` -> `NetReply`            |
| `admin/world/fault`                   | world     | one fault (swarm_config/faults.py) ->  |
|                                       |           | `FaultReply`                           |
| `admin/launcher/status`               | launcher  | `LauncherStatusReply`                  |
| `admin/launcher/kill`                 | launcher  | `ProcessRequest` -> `KillReply`        |
| `admin/launcher/restart`              | launcher  | `ProcessRequest` -> `RestartReply`     |
| `admin/launcher/stop`                 | launcher  | `ProcessRequest` -> `StopReply`        |
| `admin/launcher/cont`                 | launcher  | `ProcessRequest` -> `ContReply`        |

Every admin reply is either its verb's reply model (`ok` true) or an `AdminError` (`ok` false,
with the reason).  Readers tolerate fields they do not know (`extra="ignore"`), so a producer may
add a field without breaking older consumers; a payload that is not JSON or misses a required
field is refused as a whole (`parse_message` returns None, and the reader counts it).
"""

from __future__ import annotations

import enum
import json
from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from swarm_config.faults import RegisterFault, RunEvent
from swarm_config.radio import BurstLoss, LinkProfile

Pose = tuple[float, float, float]
"""x_m, y_m, theta_rad."""
Axes = tuple[float, float, float]
"""One value per axis of eq. 14: x, y, theta."""

Role = Literal["leader", "follower"]

MAX_MESSAGE_TIME_S = 1e9
"""The largest simulated time, in seconds either side of 0, a telemetry sample may carry (some
31 years): its stamp in integer nanoseconds, which the world keys samples by, stays finite."""


class Message(BaseModel):
    """Base of every JSON message: immutable, unknown fields ignored when read, and no NaN or
    infinity in a float field (no producer sends one: pydantic writes them as null), so a reader
    never does arithmetic on one from the network."""

    model_config = ConfigDict(extra="ignore", frozen=True, allow_inf_nan=False)

    def to_json_bytes(self) -> bytes:
        return self.model_dump_json().encode()


M = TypeVar("M", bound=BaseModel)


def parse_message(model: type[M], payload: bytes | str) -> M | None:
    """The payload as `model`, or None when it is not JSON or does not fit the model."""
    message = parse_message_or_reason(model, payload)
    return None if isinstance(message, MessageDropReason) else message


class MessageDropReason(enum.Enum):
    """Why a reader refused a JSON message."""

    NOT_JSON = "not_json"
    """Not UTF-8 JSON text (or nested too deep to read)."""
    DOES_NOT_FIT = "does_not_fit"
    """JSON, but a required field is missing or a field has the wrong type or value."""


def parse_message_or_reason(model: type[M], payload: bytes | str) -> M | MessageDropReason:
    """The payload as `model`, or why it was refused.

    Read and validated in one pass by pydantic-core (`model_validate_json`), with no Python
    objects built for the JSON first: a robot's telemetry in 8 µs instead of 21 with
    `json.loads` and `model_validate` (docs/scale.md, "The world's intake").  The
    text must be UTF-8 JSON (RFC 8259): other encodings and lone surrogates are `NOT_JSON`."""
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        if any(error["type"] == "json_invalid" for error in exc.errors(include_url=False)):
            return MessageDropReason.NOT_JSON
        return MessageDropReason.DOES_NOT_FIT


# -- robot -> viewers ---------------------------------------------------------------------------


class LoopTimingReport(Message):
    """Control-loop period jitter and deadline misses of one robot (DESIGN.md §8, timing)."""

    ticks: int = Field(ge=0)
    deadline_misses: int = Field(ge=0)
    period_jitter_p99_ms: float | None = None
    recent_miss_ticks: tuple[int, ...] = ()
    """Tick numbers of the last few misses."""


class TelemetryMessage(Message):
    """`swarm/<swarm>/telemetry/<robot>`: what one robot's firmware reports about itself.

    The control fields (desired ... active) are absent before the first control tick."""

    robot: str
    t_s: float = Field(ge=-MAX_MESSAGE_TIME_S, le=MAX_MESSAGE_TIME_S)
    role: Role | None = None
    """Whether the robot acts as leader now (robot_firmware/leadership.py), not its scenario
    role: after a failover another robot leads."""
    term: int | None = Field(default=None, ge=0)
    """The leader term the robot is in (the term its frames carry)."""
    leader: str | None = None
    """The robot it follows or, leading, itself; None while it knows no live leader."""
    localised: bool = False
    estimate: Pose | None = None
    frames: dict[str, int] = Field(default_factory=dict)
    """The frame decoder's counters: accepted, and every drop under its reason."""
    bus_errors: int = 0
    malformed_sense: int = 0
    """Sense messages refused, all reasons."""
    dropped_sense: dict[str, int] = Field(default_factory=dict)
    """Sense messages refused per reason (robot_firmware/net/wire.py `WireDropReason`)."""
    unlocalised_peer_frames: int = 0
    """Authentic radio frames not used because their sender had no fix yet."""
    safe_stopped: bool = False
    """No sense message for the sense time-out: motors off, watchdog no longer kicked."""
    safe_stops: int = 0
    """Safe stops entered since the robot started."""
    sonar_failed: bool = False
    """The sonar ring heard nothing while a peer was in its reach, sweep after sweep: the robot
    holds still until it hears again (robot_firmware/sonar_health.py)."""
    sonar_failures: int = 0
    """How often the sonar ring was taken as failed since the robot started."""
    timing: LoopTimingReport | None = None
    sonar_range_m: tuple[float | None, ...] = ()
    """Per transducer: the gap to the nearest echo, None when nothing was heard."""
    sonar_echoes_m: tuple[tuple[float, float], ...] | None = None
    """Where the last sonar sweep puts echoes, [x_m, y_m] in the world seen from the estimated
    pose, one per transducer that heard one."""
    desired: Pose | None = None
    error: Pose | None = None
    delta_k: Axes | None = None
    kp: Axes | None = None
    ki: Axes | None = None
    kd: Axes | None = None
    """Gains of the redundant PID law (eq. 14) per axis, as the fuzzy scheduler (Table 2) sets
    them."""
    repulsion_mps: tuple[float, float] | None = None
    wheel_speed_radps: tuple[float, float, float, float] | None = None
    active: bool | None = None
    register_faults: tuple[str, ...] = ()
    """The register faults active in the robot's FPGA model, each as `name(field=value, ...)`
    (robot_firmware/fpga/faults.py `fault_label`)."""


# -- world -> viewers ---------------------------------------------------------------------------


class RobotTruth(Message):
    pose: Pose
    alive: bool = True


class RadioStats(Message):
    """The radio medium's counters since the world started."""

    profile: LinkProfile = LinkProfile()
    broadcasts: int = 0
    frames: int = 0
    delivered: int = 0
    dropped: int = 0
    delivery_ratio: float | None = None
    latency_p50_ms: float | None = None
    latency_p99_ms: float | None = None


class TruthMessage(Message):
    """`swarm/<swarm>/truth`: ground truth at one simulation instant."""

    t_s: float
    tick: int = 0
    robots: dict[str, RobotTruth]
    reference: Pose
    """The leader's reference pose from the trajectory at t_s."""
    radio: RadioStats = RadioStats()


# -- admin: common ------------------------------------------------------------------------------


class AdminRefusal(enum.StrEnum):
    """Why an admin request was refused (`AdminError.reason`)."""

    INVALID_REQUEST = "invalid_request"
    """The body does not fit the verb's request model (a field missing, unknown or invalid)."""
    NOT_JSON = "not_json"
    """The body is not a JSON document."""
    NOT_YAML = "not_yaml"
    """The body is not a YAML (or JSON) document."""
    UNKNOWN_VERB = "unknown_verb"
    UNKNOWN_ROBOT = "unknown_robot"
    UNKNOWN_PROCESS = "unknown_process"
    """No process of that name under the launcher."""
    UNKNOWN_PROFILE = "unknown_profile"
    BUS_ERROR = "bus_error"
    """The register access was refused by the bus."""
    HANDLER_FAILED = "handler_failed"
    """The handler raised: a bug, answered by the dispatcher's safety net."""
    UNREACHABLE = "unreachable"
    """The process a request is forwarded to is not up, or did not answer in time."""
    BUSY = "busy"
    """Too many requests already wait for the process's loop (a flood): ask again."""
    CANNOT_START = "cannot_start"
    """The launcher cannot start the process: what it needs of the run folder is gone."""
    EXPIRED = "expired"
    """The request's sender had stopped waiting before it could be served, or it came after
    the router had closed the session it came on (robot_firmware/net/request_deadline.py): not
    carried out."""


def refusal_of(error: ValidationError) -> AdminRefusal:
    """`not_json` when pydantic could not read the body as JSON at all, else `invalid_request`."""
    if any(item["type"] == "json_invalid" for item in error.errors(include_url=False)):
        return AdminRefusal.NOT_JSON
    return AdminRefusal.INVALID_REQUEST


class AdminError(Message):
    """Any admin verb's refusal: nothing was changed."""

    ok: Literal[False] = False
    error: str
    reason: str = AdminRefusal.INVALID_REQUEST.value
    """An `AdminRefusal` value; a string, so that a reader older than a new reason still reads
    the refusal."""


class AdminOk(Message):
    ok: Literal[True] = True


# -- admin: robot -------------------------------------------------------------------------------


class RobotStatusReply(TelemetryMessage):
    """`admin/<robot>/status`: the robot's telemetry, now, and how it runs."""

    ok: Literal[True] = True
    register_model: Literal["python", "mypyc"]
    """How this robot runs its register model and drivers: from their source, or compiled by
    mypyc (robot_firmware/native.py; a robot without the build for its sources runs them from
    source)."""


class RegsRequest(Message):
    """`admin/<robot>/regs`: like `devmem`. An empty body is a dump."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    op: Literal["dump", "read", "write"] = "dump"
    address: Annotated[int, Field(ge=0, le=0xFFFF_FFFF, strict=True)] | None = None
    value: Annotated[int, Field(ge=0, le=0xFFFF_FFFF, strict=True)] | None = None


class RegisterRow(Message):
    address: int
    peripheral: str
    name: str
    """The register's name within its peripheral."""
    access: str
    value: int


class RegsDumpReply(AdminOk):
    registers: tuple[RegisterRow, ...]


class RegsAccessReply(AdminOk):
    address: int
    value: int
    name: str | None = None
    """peripheral.register at the address."""


class RegsBusError(AdminError):
    """A refused register access, reported as the bus error it is."""

    address: int
    reason: str = AdminRefusal.BUS_ERROR.value


RegsReply = RegsDumpReply | RegsAccessReply | RegsBusError | AdminError


class ParamsReply(AdminOk):
    """`admin/<robot>/params`: the fuzzy scheduler's parameters (a FuzzyParameters mapping),
    or, after a replacement, the new rule count."""

    parameters: dict[str, object] | None = None
    rule_count: int | None = None


class RegisterFaultsReply(AdminOk):
    """`admin/<robot>/fault`: the register faults active in the robot's FPGA model after the
    request (oldest first; an empty request only lists them)."""

    robot: str
    active: tuple[Annotated[RegisterFault, Field(discriminator="fault")], ...] = ()


# -- admin: world -------------------------------------------------------------------------------


class LockstepSeat(Message):
    """One robot's place at the lockstep barrier (world/lockstep.py)."""

    live: bool
    last_act_tick: int
    frames_owed: int
    owes_from_tick: int
    excused: int = 0
    """Ticks that went on without this robot's answer: a message to or from it was lost
    (world/lockstep.py, "Lost messages")."""


class RefusedInput(Message):
    """What the world refused from the robots since it started (docs/summary-schema.md): the
    same figures as summary.json's `malformed_acts`, `malformed_telemetry`, `refused_frames`
    and `over_budget`."""

    malformed_acts: int = 0
    malformed_telemetry: int = 0
    refused_frames: dict[str, int] = Field(default_factory=dict)
    """Per reason: `unknown_transmitter`, `claimed_another_sender`."""
    over_budget: dict[str, dict[str, int]] = Field(default_factory=dict)
    """Per kind (`act`, `frame`, `telemetry`), per robot (world/input_budget.py)."""

    def total(self) -> int:
        return (
            self.malformed_acts
            + self.malformed_telemetry
            + sum(self.refused_frames.values())
            + sum(sum(per_robot.values()) for per_robot in self.over_budget.values())
        )

    def describe(self) -> str:
        """One line for a terminal: the non-zero figures, the robots over budget named."""
        parts = [
            f"{count} {what}"
            for what, count in (
                ("malformed acts", self.malformed_acts),
                ("malformed telemetry", self.malformed_telemetry),
                *((f"frames ({reason})", n) for reason, n in self.refused_frames.items()),
            )
            if count
        ]
        for kind, per_robot in self.over_budget.items():
            over = ", ".join(f"{robot} {n}" for robot, n in per_robot.items() if n)
            if over:
                parts.append(f"{kind} over budget: {over}")
        return "; ".join(parts) if parts else "none"


class RunMetrics(Message):
    """The run's metrics so far (DESIGN.md §8), as in summary.json."""

    leader: str
    leader_tracking_rms_m: float | None = None
    leader_tracking_rms_all_m: float | None = None
    leader_heading_rms_rad: float | None = None
    leader_heading_rms_all_rad: float | None = None
    formation_rms_m: dict[str, float | None] = Field(default_factory=dict)
    formation_rms_all_m: dict[str, float | None] = Field(default_factory=dict)
    formation_max_m: float | None = None
    formation_max_all_m: float | None = None
    nominal_share: dict[str, float | None] = Field(default_factory=dict)
    min_robot_separation_m: float | None = None
    min_obstacle_clearance_m: float | None = None
    collisions: int = 0
    mean_abs_error_sum: float | None = None


ClockMode = Literal["lockstep", "real_time"]


class LockstepProfileReport(Message):
    """Where a lockstep tick's wall time goes (world/lockstep.py `LockstepProfile`)."""

    ticks: int
    phase_ms_per_tick: dict[str, float]
    """Mean wall milliseconds per tick in each phase, in the order of `TICK_PHASES`."""
    answer_p50_ms: dict[str, float]
    """Per robot: median wall time from the tick's sense message out to its act message in."""


class LinkOverride(Message):
    """Links whose profile a `swarm fault net` changed, and what it set on them; the rest of
    each one's profile is the running one."""

    links: tuple[tuple[str, str], ...]
    """Each pair once; an override holds in both directions."""
    latency_ms: float | None = None
    jitter_ms: float | None = None
    loss: float | None = None
    burst: BurstLoss | None = None


class NetworkFaultsReport(Message):
    """The network faults in effect on top of the running link profile (`swarm fault net`,
    `swarm fault partition`); `swarm fault heal` clears them all."""

    overrides: tuple[LinkOverride, ...] = ()
    cut_links: tuple[tuple[str, str], ...] = ()


class WorldStatusReply(AdminOk):
    """`admin/world/status`."""

    t_s: float
    tick: int
    clock_mode: ClockMode
    real_time_factor: float | None = None
    """Simulated seconds per wall second since time started."""
    live: tuple[str, ...]
    robots: tuple[str, ...]
    radio: RadioStats
    network_faults: NetworkFaultsReport | None = None
    """The network faults in effect on top of `radio.profile`; None without any."""
    metrics: RunMetrics
    position_errors_m: dict[str, float]
    """Each robot's distance from its reference now (trajectory or slot, DESIGN.md §8)."""
    lockstep_owed: dict[str, LockstepSeat]
    lockstep_profile: LockstepProfileReport | None = None
    """Lockstep only: where the ticks' wall time went since time started."""
    refused_input: RefusedInput = RefusedInput()
    write_failures: dict[str, int] = {}
    """Writes of the run folder's files that failed (a full disk), per file: "summary.json",
    "checkpoint", "events.jsonl"; the run goes on without them (docs/robustness.md)."""


class NetProfileRequest(Message):
    """`admin/world/net` by name: one of the named link profiles."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    profile: str


class NetReply(AdminOk):
    profile: LinkProfile
    faults: NetworkFaultsReport | None = None
    """The network faults in effect on top of `profile`; None without any (before, `net get`
    showed the profile alone, while a `fault net` override dropped nine frames in ten)."""


class FaultReply(AdminOk):
    """`admin/world/fault`: the fault took effect at a tick boundary; `event` is what the run
    recorded (a line of `events.jsonl`), `reply` the answer of the robot or launcher it was
    forwarded to, if any."""

    event: RunEvent
    reply: dict[str, object] | None = None


# -- admin: launcher ----------------------------------------------------------------------------


class ProcessStatus(Message):
    pid: int | None
    running: bool
    exit_code: int | None
    killed: bool
    stopped: bool = False
    """SIGSTOPped (`admin/launcher/stop`) and not continued since: alive but frozen."""
    restarts: int
    log: str


class LauncherStatusReply(AdminOk):
    """`admin/launcher/status`: the processes `swarm up` supervises."""

    processes: dict[str, ProcessStatus]


class ProcessRequest(Message):
    """`admin/launcher/kill`, `.../restart`, `.../stop` and `.../cont`: which of the launcher's
    processes (a robot, `world`, `router` or `dashboard`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    process: str


class KillReply(AdminOk):
    killed: bool
    """False when the robot was not running."""


class RestartReply(AdminOk):
    restarted: str
    pid: int | None


class StopReply(AdminOk):
    stopped: bool
    """False when the process was not running."""


class ContReply(AdminOk):
    continued: bool
    """False when the process was not running."""


AdminReply = (
    RobotStatusReply
    | RegsDumpReply
    | RegsAccessReply
    | ParamsReply
    | RegisterFaultsReply
    | WorldStatusReply
    | NetReply
    | FaultReply
    | LauncherStatusReply
    | KillReply
    | RestartReply
    | StopReply
    | ContReply
    | AdminError
)


def parse_reply(model: type[M], payload: bytes) -> M | AdminError | None:
    """An admin reply: `model` when ok, `AdminError` when refused, None when it fits neither."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if isinstance(data, dict) and data.get("ok") is False:
        try:
            return AdminError.model_validate(data)
        except ValidationError:
            return None
    try:
        return model.model_validate(data)
    except ValidationError:
        return None


_ANY_REGS_REPLY: TypeAdapter[RegsReply] = TypeAdapter(RegsReply)


def parse_regs_reply(payload: bytes) -> RegsReply | None:
    try:
        return _ANY_REGS_REPLY.validate_json(payload)
    except ValidationError:
        return None

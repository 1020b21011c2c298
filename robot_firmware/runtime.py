"""The robot process: one robot's fabric and firmware, wired to the swarm over Zenoh.

Inputs arrive in Zenoh callbacks, which only queue them (DESIGN: never block in a callback):
`wire/<robot>/sense` (the pins) and admin queries; the frames the radio medium delivers on
`radio/rx/<robot>` (in bundles, robot_firmware/net/radio_bundle.py) wait in a Zenoh ring channel
until the loop takes them, with no callback.
The main loop owns the fabric and the firmware and is a thin shell around the pure
`TickScheduler` (robot_firmware/tick_scheduler.py), which decides when a tick runs and at
what simulation time: in real time a 100 Hz loop on the monotonic clock, in lockstep (when the
world's sense messages say so) one tick per sense message, answered by an act message carrying
the same tick number.  Each tick applies the sense messages that arrived to the pins, hands over
the radio frames, runs the 5C tick, publishes the PWM pins (`wire/<robot>/act`) and any radio
frame, and advances the fabric to the tick's time.  Until the first sense message there is no
time and the control loop waits (admin queries are still served).  In real time, when no sense
message has come for the scheduler's sense time-out (the world is gone, or this process was
frozen), each period is a safe stop instead of a tick: the firmware holds the motors off and
no longer kicks the watchdog, the fabric's time runs on so the watchdog IP cuts the PWM, and
the act message says so (duty 0, disabled, then watchdog expired).  The first tick after the
gap re-localises and drops stale peer state (`Firmware.resume`).
A liveliness token `alive/robot/<name>` tells the world and the launcher that the robot is up.
The robot also watches its peers' tokens (`alive/robot/*`): a token that goes tells its leader
election (robot_firmware/leadership.py) that the peer is gone, without waiting for its frames
to go stale (in real time; in lockstep only frames count, so a failover replays); changes are
queued by the callback and handed over at the next tick.
Telemetry (estimate, desired pose, gains, fuzzy output, counters, loop timing) is published at
its own rate.
The admin verb `fault` injects one register fault into the robot's FPGA model
(robot_firmware/fpga/faults.py), between ticks like every admin query; a forced watchdog expiry
lands after the firmware's tick, before the act message, and `tick_slow` makes every control
tick sleep its extra milliseconds before the act message leaves, as an overloaded CPU would
(a sleep, not a busy wait: the other robots of the host have CPUs of their own on a real swarm).
"""

from __future__ import annotations

import gc
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import yaml
import zenoh
from pydantic import (
    ConfigDict,
    Field,
    FilePath,
    PositiveFloat,
    ValidationError,
    field_validator,
    model_validator,
)

from robot_firmware import native
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from robot_firmware.drivers import Drivers
from robot_firmware.firmware import Firmware, RobotMission, TickReport
from robot_firmware.fpga.fabric import Fabric, FabricConfig
from robot_firmware.net.admin import AdminQueue, Handler
from robot_firmware.net.frames import derive_frame_key, swarm_hash_from_name
from robot_firmware.net.keys import SwarmKeys, check_name
from robot_firmware.net.messages import (
    AdminError,
    AdminRefusal,
    LoopTimingReport,
    ParamsReply,
    RegisterFaultsReply,
    RobotStatusReply,
    TelemetryMessage,
    refusal_of,
)
from robot_firmware.net.radio_bundle import FRAME_RING, split_bundle
from robot_firmware.net.session import (
    DEFAULT_ENDPOINT,
    open_client_until_stopped,
    split_endpoints,
)
from robot_firmware.net.wire import (
    ActMessage,
    WireCounters,
    WireDropReason,
    encode_act,
    parse_sense,
)
from robot_firmware.pins import apply_sense
from robot_firmware.regs_admin import handle_regs_request
from robot_firmware.tick_scheduler import LoopStallWatch, RunTick, SafeStop, TickScheduler, Wait
from swarm_config.credentials import CREDENTIALS_FILE_ENV, CredentialsFile
from swarm_config.faults import FAULT_ADAPTER, REGISTER_FAULT_ADAPTER
from swarm_config.scenario import load_fuzzy_parameters, load_scenario
from swarm_config.settings import (
    Endpoints,
    LayeredSettings,
    describe_validation_error,
    parse_yaml,
)

log = logging.getLogger("swarm.robot")

NS_PER_S = 1_000_000_000
FRAME_POLL_S = 0.0005
"""How often a lockstep tick waiting for announced radio frames looks for them."""


class RobotConfig(LayeredSettings):
    """Settings of one robot process: YAML file, then environment, then flags."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    swarm: str = "lab"
    scenario: Path
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT], min_length=1)
    zenoh_config: FilePath | None = None
    credentials: CredentialsFile = Field(default=None, validate_default=True, repr=False)
    """Router user and password, the frames' secret and the run id: read from the file named
    by --credentials or $SWARM_CREDENTIALS_FILE (swarm_config/credentials.py)."""
    telemetry_rate_hz: PositiveFloat = 20.0
    fabric_step_ns: int = Field(default=1_000_000, gt=0)

    @field_validator("name", "swarm")
    @classmethod
    def _key_chunk(cls, value: str) -> str:
        return check_name("robot or swarm", value)

    @model_validator(mode="after")
    def _credentials_are_this_robots(self) -> RobotConfig:
        creds = self.credentials
        if creds.identity != self.name or creds.swarm != self.swarm:
            raise ValueError(
                f"the credentials file is {creds.identity!r} of swarm {creds.swarm!r}, not "
                f"{self.name!r} of swarm {self.swarm!r}"
            )
        if creds.swarm_key is None:
            raise ValueError(f"the credentials of {self.name!r} hold no swarm key")
        return self

    WHAT: ClassVar[str] = "robot configuration"
    ENV: ClassVar[Mapping[str, str]] = {
        "name": "ROBOT_NAME",
        "swarm": "SWARM_NAME",
        "scenario": "SWARM_SCENARIO",
        "connect": "ZENOH_CONNECT",
        "zenoh_config": "ZENOH_CONFIG",
        "credentials": CREDENTIALS_FILE_ENV,
        "telemetry_rate_hz": "TELEMETRY_RATE_HZ",
    }
    ENV_ALIASES: ClassVar[Mapping[str, str]] = {"name": "ROBOT_ID"}
    ENV_PARSERS: ClassVar[Mapping[str, Callable[[str], object]]] = {"connect": split_endpoints}


class RobotProcess:
    """A robot on the swarm: fabric + firmware + Zenoh glue."""

    def __init__(self, config: RobotConfig) -> None:
        self.config = config
        scenario = load_scenario(config.scenario)
        self.fuzzy_parameters = (
            load_fuzzy_parameters(scenario.fuzzy_parameter_file)
            if scenario.fuzzy_parameter_file is not None
            else FuzzyParameters.table2_defaults()
        )
        self.mission = RobotMission.from_scenario(
            scenario, config.name, self.fuzzy_parameters.rule_base()
        )
        self.keys = SwarmKeys(config.swarm)
        sonar_count = self.mission.sonar_count
        self.fabric = Fabric(FabricConfig(n_sonar=sonar_count))
        self.drivers = Drivers.attach(self.fabric.bus, sonar_count)
        self.firmware = Firmware(
            self.mission,
            self.drivers,
            derive_frame_key(config.credentials.swarm_key_bytes(), config.swarm),
            swarm_hash=swarm_hash_from_name(config.swarm),
            run_id=config.credentials.run_id_bytes,
        )
        self.period_ns = round(self.mission.params.control_period_s * NS_PER_S)
        self.scheduler = TickScheduler(self.period_ns)
        self.stall_watch = LoopStallWatch()
        """Whether this process's loop stalled lately: then peers' tokens do not count."""
        self._sense: deque[tuple[bytes, int]] = deque(maxlen=64)
        self._frames: deque[bytes] = deque(maxlen=1024)
        self._peer_tokens: deque[tuple[str, bool]] = deque(maxlen=1024)
        self._admin = AdminQueue()
        self._wake = threading.Event()
        self.sense_counters = WireCounters()
        """Sense messages applied, and refused per `WireDropReason`."""
        self.stop = threading.Event()
        self._fabric_time_ns = 0
        self._fabric_offset_ns = 0
        """Fabric time minus world time; changes only when the world's clock jumps (a new
        epoch), so the fabric's clock never runs backwards."""
        self._telemetry_period_ns = round(NS_PER_S / config.telemetry_rate_hz)
        self._next_telemetry_ns = 0
        self._telemetry_count = 0
        self._jitter_p99_ms: float | None = None
        self.last_report: TickReport | None = None

    # -- callbacks (zenoh threads): queue and return -------------------------------------

    def _on_sense(self, sample: zenoh.Sample) -> None:
        self._sense.append((sample.payload.to_bytes(), time.monotonic_ns()))
        self._wake.set()

    def _collect_frames(self, received: zenoh.Handler[zenoh.Sample]) -> None:
        """Move the radio frames Zenoh has queued on `received` into the loop's queue, each
        bundle split into its frames (robot_firmware/net/radio_bundle.py; a malformed rest
        goes on as one frame, which the decoder drops and counts).

        Frames are not taken in a Python callback: Zenoh's receive thread puts each bundle in
        a ring (`FRAME_RING`, the oldest dropped when full, as the queue drops frames) and the
        loop takes them when it comes round.  A callback would wake a Python thread for each
        bundle, often of one frame in real time, to do no more than queue it."""
        frames = self._frames
        while (sample := received.try_recv()) is not None:
            frames.extend(split_bundle(sample.payload.to_bytes()))

    def _on_peer_token(self, sample: zenoh.Sample) -> None:
        name = SwarmKeys.last_chunk(str(sample.key_expr))
        self._peer_tokens.append((name, sample.kind == zenoh.SampleKind.PUT))

    # -- main loop: the scheduler decides, this shell does the I/O ------------------------

    def run(self) -> int:
        cfg = self.config
        session = open_client_until_stopped(
            self.stop, cfg.connect, cfg.zenoh_config, cfg.credentials
        )
        if session is None:
            log.info("stopped before a router let %s in", cfg.name)
            return 0
        with session:
            name = cfg.name
            session.declare_subscriber(self.keys.sense(name), self._on_sense)
            frame_ring = session.declare_subscriber(
                self.keys.radio_rx(name), zenoh.handlers.RingChannel(FRAME_RING)
            )
            session.declare_queryable(self.keys.admin(name, "*"), self._admin.on_query)
            act_pub = session.declare_publisher(self.keys.act(name))
            tx_pub = session.declare_publisher(self.keys.radio_tx(name))
            telemetry_pub = session.declare_publisher(self.keys.telemetry(name))
            token = session.liveliness().declare_token(self.keys.alive("robot", name))
            session.liveliness().declare_subscriber(
                self.keys.alive_all("robot"), self._on_peer_token, history=True
            )
            self.firmware.boot(self._tick_fabric)
            gc.collect()
            gc.freeze()  # boot-time objects leave the collector's work: shorter pauses in the loop
            log.info("robot %s up (%s)", name, "leader" if self.firmware.is_leader else "follower")
            while not self.stop.is_set():
                late_ns = self.stall_watch.came_round(time.monotonic_ns())
                if late_ns:
                    log.warning(
                        "this process stalled for %.1f s (frozen or starved): peers' liveliness "
                        "tokens do not count for %.0f s while its link to the router settles",
                        late_ns / NS_PER_S,
                        self.stall_watch.settle_ns / NS_PER_S,
                    )
                self._serve_queries()
                self._take_sense()
                self._collect_frames(frame_ring.handler)
                decision = self.scheduler.poll(time.monotonic_ns(), len(self._frames))
                if isinstance(decision, Wait):
                    # A lockstep tick short of its announced frames looks for them again
                    # shortly: they come on no callback.  They are seldom late, as the world
                    # puts them before the sense message that announces them.
                    timeout_s = (
                        min(decision.timeout_s, FRAME_POLL_S)
                        if self.scheduler.awaits_frames
                        else decision.timeout_s
                    )
                    self.stall_watch.due(time.monotonic_ns() + round(timeout_s * NS_PER_S))
                    self._wake.wait(timeout_s)
                    self._wake.clear()
                    continue
                self._run_period(decision, act_pub, tx_pub, telemetry_pub)
                self.scheduler.finished(decision, time.monotonic_ns())
                self.stall_watch.due(time.monotonic_ns())
            token.undeclare()
        return 0

    def _run_period(
        self,
        decision: RunTick | SafeStop,
        act_pub: zenoh.Publisher,
        tx_pub: zenoh.Publisher,
        telemetry_pub: zenoh.Publisher,
    ) -> None:
        """What the scheduler decided: a safe stop, or a control tick (after a gap in the sense
        messages, on fresh state)."""
        if isinstance(decision, SafeStop):
            self._safe_stop(decision, act_pub, telemetry_pub)
            return
        if decision.new_epoch:
            log.info(
                "new world epoch %d at t = %.3f s: schedulers re-synchronised, peer state dropped",
                self.scheduler.epoch,
                decision.sim_time_ns / NS_PER_S,
            )
            # The fabric's own clock runs on from where it is: only its offset to the world's
            # time changes.
            self._fabric_offset_ns = self._fabric_time_ns - decision.sim_time_ns
            self._next_telemetry_ns = 0
            self.firmware.new_world_epoch(decision.sim_time_ns)
        elif decision.resumed:
            log.info("sense messages back: re-localising, stale peer state dropped")
            # During the gap the fabric ran on the extrapolated time; a world that held its
            # time (world/realtime_guard.py) is behind that: the fabric runs on from where it
            # is instead of standing still (no sonar, no timers) until the world catches up.
            self._fabric_offset_ns = max(
                self._fabric_offset_ns, self._fabric_time_ns - decision.sim_time_ns
            )
            self._next_telemetry_ns = min(self._next_telemetry_ns, decision.sim_time_ns)
            self.firmware.resume(decision.sim_time_ns)
        self._control(decision.sim_time_ns, decision.tick, act_pub, tx_pub, telemetry_pub)

    def _take_sense(self) -> None:
        """Apply every queued sense message to the pins in order and tell the scheduler."""
        while self._sense:
            raw, arrival = self._sense.popleft()
            message = parse_sense(raw, self.mission.sonar_count)
            self.sense_counters.count(message)
            if isinstance(message, WireDropReason):
                continue
            apply_sense(self.fabric, message)
            self.scheduler.sensed(
                message.t_ns,
                message.tick,
                message.lockstep,
                message.radio_frames,
                arrival,
                message.epoch,
            )

    def _sim_time_ns(self, mono_now_ns: int) -> int:
        sim_now = self.scheduler.sim_time_ns(mono_now_ns)
        if sim_now is None:
            return self._fabric_time_ns - self._fabric_offset_ns + self.period_ns
        return sim_now

    def _advance_fabric_to(self, world_now_ns: int) -> None:
        """Run the fabric up to world time `world_now_ns` (never backwards)."""
        target_ns = world_now_ns + self._fabric_offset_ns
        if target_ns > self._fabric_time_ns:
            self._tick_fabric(target_ns - self._fabric_time_ns)

    def _tick_fabric(self, dt_ns: int) -> None:
        self.fabric.advance(dt_ns, self.config.fabric_step_ns)
        self._fabric_time_ns = self.fabric.now_ns

    def _control(
        self,
        now_ns: int,
        tick: int,
        act_pub: zenoh.Publisher,
        tx_pub: zenoh.Publisher,
        telemetry_pub: zenoh.Publisher,
    ) -> None:
        self._advance_fabric_to(now_ns)
        # In lockstep the tokens' wall-clock instants must not decide a failover (replays).
        self.firmware.lockstep = self.scheduler.lockstep
        self.firmware.tokens_suspended = self.stall_watch.settling(time.monotonic_ns())
        while self._peer_tokens:
            peer, alive = self._peer_tokens.popleft()
            self.firmware.set_peer_alive(peer, alive, now_ns)
        while self._frames:
            self.firmware.receive(self._frames.popleft(), now_ns)
        report = self.firmware.control_tick(now_ns)
        self.last_report = report
        faults = self.fabric.faults
        faults.land_pending()
        if faults.tick_extra_s:
            time.sleep(faults.tick_extra_s)  # tick_slow: the overloaded CPU finishes late
        frames_sent = 0
        if report.frame is not None:
            tx_pub.put(report.frame)
            frames_sent = 1
        self._publish_act(tick, frames_sent, act_pub)
        self._publish_telemetry(now_ns, telemetry_pub)

    def _safe_stop(
        self, decision: SafeStop, act_pub: zenoh.Publisher, telemetry_pub: zenoh.Publisher
    ) -> None:
        """A period with no sense messages: motors off, no kick; the fabric's time runs on."""
        if decision.entered:
            log.warning(
                "no sense message for %.0f ms: motors off, watchdog no longer kicked",
                self.scheduler.sense_timeout_ns / 1e6,
            )
        now_ns = decision.sim_time_ns
        self._advance_fabric_to(now_ns)
        self.firmware.safe_stop()
        self.fabric.faults.land_pending()
        self._publish_act(0, 0, act_pub)
        self._publish_telemetry(now_ns, telemetry_pub)

    def _publish_act(self, tick: int, frames_sent: int, act_pub: zenoh.Publisher) -> None:
        actuation = self.fabric.hw_read_actuation()
        duty = actuation.duty
        enabled = actuation.enabled
        act_pub.put(
            encode_act(
                ActMessage(
                    tick=tick,
                    duty=(duty[0], duty[1], duty[2], duty[3]),
                    enabled=(enabled[0], enabled[1], enabled[2], enabled[3]),
                    watchdog_expired=actuation.watchdog_expired,
                    radio_frames=frames_sent,
                )
            )
        )

    def _publish_telemetry(self, now_ns: int, telemetry_pub: zenoh.Publisher) -> None:
        if now_ns >= self._next_telemetry_ns:
            self._next_telemetry_ns = now_ns + self._telemetry_period_ns
            self._telemetry_count += 1
            if self._telemetry_count % 20 == 1:  # the percentile is refreshed about once a second
                self._jitter_p99_ms = self.scheduler.timing.jitter_p99_ms()
            telemetry_pub.put(self.telemetry(now_ns).to_json_bytes())

    def _leadership_fields(self) -> dict[str, Any]:
        leadership = self.firmware.leadership
        if leadership is None:
            return {}
        leader = leadership.index if leadership.is_leader else leadership.leader
        return {
            "term": leadership.term,
            "leader": None if leader is None else self.mission.names[leader],
        }

    def _telemetry_fields(self, now_ns: int) -> dict[str, Any]:
        """Plain Python values of the message's types (`tolist` turns float64 arrays into
        floats in one call each)."""
        report = self.last_report
        est = self.firmware.state.estimator
        timing = self.scheduler.timing
        fields: dict[str, Any] = {
            "robot": self.config.name,
            "t_s": now_ns / NS_PER_S,
            "role": "leader" if self.firmware.is_leader else "follower",
            **self._leadership_fields(),
            "localised": bool(est.localised),
            "estimate": tuple(est.pose.tolist()),
            "frames": self.firmware.decoder.counters.as_dict(),
            "bus_errors": self.drivers.bus_errors,
            "malformed_sense": self.sense_counters.dropped_total,
            "dropped_sense": self.sense_counters.dropped_as_dict(),
            "unlocalised_peer_frames": self.firmware.unlocalised_peer_frames,
            "safe_stopped": self.scheduler.safe_stopped,
            "safe_stops": self.scheduler.safe_stops,
            "sonar_failed": self.firmware.sonar_health.failed,
            "sonar_failures": self.firmware.sonar_health.failures,
            "timing": LoopTimingReport.model_construct(
                ticks=timing.ticks,
                deadline_misses=timing.deadline_misses,
                period_jitter_p99_ms=self._jitter_p99_ms,
                recent_miss_ticks=tuple(timing.recent_miss_ticks),
            ),
            "sonar_range_m": tuple(
                g if math.isfinite(g) else None for g in self.firmware.sonar_gap_m.tolist()
            ),
            "sonar_echoes_m": self.firmware.sonar_echo_points_m(),
            "register_faults": self.fabric.faults.labels,
        }
        if report is not None:
            o = report.outputs
            fields.update(
                desired=tuple(o.desired_pose.tolist()),
                error=tuple(o.error.tolist()),
                delta_k=tuple(o.delta_k.tolist()),
                kp=tuple(o.kp.tolist()),
                ki=tuple(o.ki.tolist()),
                kd=tuple(o.kd.tolist()),
                repulsion_mps=tuple(o.repulsion_mps.tolist()),
                wheel_speed_radps=tuple(o.wheel_speed_radps.tolist()),
                active=bool(o.active),
            )
        return fields

    def telemetry(self, now_ns: int) -> TelemetryMessage:
        """This robot's telemetry now: built from its own state, field by field with the
        message's types, so it is not validated again on the way out (the readers validate
        it); at 20 Hz the validation cost a tenth of the robot's loop."""
        return TelemetryMessage.model_construct(**self._telemetry_fields(now_ns))

    def _params_request(self, payload: bytes) -> ParamsReply | AdminError:
        """Get the fuzzy scheduler's parameters, or replace them with a new parameter file.

        The file (YAML or JSON text) is validated first; a bad one is refused with the reason
        and the running parameters stay.  Queries are served between control ticks, so a new
        scheduler takes effect at the next tick.
        """
        if not payload:
            return ParamsReply(parameters=self.fuzzy_parameters.model_dump())
        try:
            data = parse_yaml(payload.decode("utf-8"))
        except (ValueError, yaml.YAMLError, RecursionError) as exc:
            # ValueError: not UTF-8, or a date that does not exist (PyYAML builds one from
            # 2001-02-30); RecursionError: nested too deep for PyYAML's composer.
            return AdminError(
                error=f"fuzzy parameters refused: not YAML or JSON: {exc}",
                reason=AdminRefusal.NOT_YAML,
            )
        try:
            parameters = FuzzyParameters.model_validate(data)
        except ValidationError as exc:
            return AdminError(error=describe_validation_error("fuzzy parameters refused", exc))
        self.firmware.set_rule_base(parameters.rule_base())
        self.fuzzy_parameters = parameters
        log.info(
            "fuzzy parameters replaced: %d x %d sets",
            len(parameters.error_centres),
            len(parameters.rate_centres),
        )
        return ParamsReply(rule_count=len(parameters.error_centres) * len(parameters.rate_centres))

    def _fault_request(self, payload: bytes) -> RegisterFaultsReply | AdminError:
        """Inject one register fault (a `swarm_config.faults` register fault as JSON) into this
        robot's FPGA model, or with an empty body list the active ones.  A malformed fault, one
        of another kind or one naming another robot is refused and changes nothing."""
        faults = self.fabric.faults
        name = self.config.name
        if payload:
            try:
                fault = REGISTER_FAULT_ADAPTER.validate_json(payload)
            except ValidationError as exc:
                return self._fault_refusal(payload, exc)
            if fault.robot != name:
                return AdminError(
                    error=f"fault refused: it names robot {fault.robot!r}; this is {name!r}",
                    reason=AdminRefusal.UNKNOWN_ROBOT,
                )
            faults.apply(fault)
            log.warning("register fault %s", fault.model_dump_json())
        return RegisterFaultsReply(robot=name, active=faults.active)

    @staticmethod
    def _fault_refusal(payload: bytes, exc: ValidationError) -> AdminError:
        try:
            other = FAULT_ADAPTER.validate_json(payload)
        except ValidationError:
            return AdminError(
                error=describe_validation_error("fault refused", exc), reason=refusal_of(exc)
            )
        return AdminError(
            error=(
                f"fault refused: {other.fault!r} is a {other.kind} fault; a robot takes register "
                "faults only (send the others to the world's fault verb)"
            ),
            reason=AdminRefusal.INVALID_REQUEST,
        )

    def admin_handlers(self) -> dict[str, Handler]:
        """The robot's admin verbs, served between control ticks."""
        return {
            "regs": lambda body: handle_regs_request(self.fabric.bus, body),
            "params": self._params_request,
            "fault": self._fault_request,
            "status": lambda _body: RobotStatusReply(
                **self._telemetry_fields(self._sim_time_ns(time.monotonic_ns())),
                register_model=native.MODE,
            ),
        }

    def _serve_queries(self) -> None:
        if self._admin.pending:  # the loop looks twice a period; a query is rare
            self._admin.serve(self.admin_handlers())

"""The robot process: one robot's fabric and firmware, wired to the swarm over Zenoh.

Inputs arrive in Zenoh callbacks, which only queue them (DESIGN: never block in a callback):
`wire/<robot>/sense` (the pins), `radio/rx/<robot>` (frames delivered by the radio medium) and
admin queries.  The main loop owns the fabric and the firmware:

* real time (default): a 100 Hz loop on the monotonic clock; each tick applies the newest
  sense message to the pins, hands over the frames that arrived, runs the 5C tick, publishes the
  PWM pins (`wire/<robot>/act`) and any radio frame, and advances the fabric by the elapsed time;
* lockstep (when the world's sense messages say so): one tick per sense message, at the world's
  simulation time, answered by an act message carrying the same tick number.

The robot's notion of time is the world's simulation time (from the last sense message plus the
time since it arrived), so frame timestamps from different robots compare; until the first sense
message arrives there is no time and the control loop waits (admin queries are still served).
A liveliness token `alive/robot/<name>` tells the world and the launcher that the robot is up.
Telemetry (estimate, desired pose, gains, fuzzy output, counters, loop timing) is published at
its own rate.
"""

from __future__ import annotations

import gc
import json
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import yaml
import zenoh
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, ValidationError, field_validator

from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from robot_firmware.drivers import Drivers
from robot_firmware.firmware import Firmware, RobotMission, TickReport
from robot_firmware.fpga.fabric import Fabric, FabricConfig
from robot_firmware.net.admin import AdminQueue
from robot_firmware.net.frames import SWARM_KEY_ENV_VAR, key_from_secret, swarm_hash_from_name
from robot_firmware.net.keys import SwarmKeys, check_name
from robot_firmware.net.session import DEFAULT_ENDPOINT, open_client, split_endpoints
from robot_firmware.net.wire import ActMessage, SenseMessage, decode_sense, encode_act
from robot_firmware.pins import apply_sense
from robot_firmware.regs_admin import handle_regs_request
from swarm_config.scenario import load_rule_base, load_scenario

log = logging.getLogger("swarm.robot")

NS_PER_S = 1_000_000_000
DEV_SWARM_SECRET = "swarm-cps development key: set SWARM_KEY"


class RobotConfig(BaseModel):
    """Settings of one robot process; environment variables fill what the command line omits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    swarm: str = "lab"
    scenario: Path
    connect: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT], min_length=1)
    zenoh_config: Path | None = None
    secret: str = Field(default=DEV_SWARM_SECRET, min_length=1, repr=False)
    telemetry_rate_hz: PositiveFloat = 20.0
    fabric_step_ns: int = Field(default=1_000_000, gt=0)

    @field_validator("name", "swarm")
    @classmethod
    def _key_chunk(cls, value: str) -> str:
        return check_name("robot or swarm", value)

    ENV: ClassVar[Mapping[str, str]] = {
        "name": "ROBOT_NAME",
        "swarm": "SWARM_NAME",
        "scenario": "SWARM_SCENARIO",
        "connect": "ZENOH_CONNECT",
        "zenoh_config": "ZENOH_CONFIG",
        "secret": SWARM_KEY_ENV_VAR,
        "telemetry_rate_hz": "TELEMETRY_RATE_HZ",
    }

    @classmethod
    def from_sources(
        cls,
        given: Mapping[str, Any],
        environ: Mapping[str, str] | None = None,
        config_file: Path | None = None,
    ) -> RobotConfig:
        """Settings from a YAML file, then environment variables (ROBOT_NAME or ROBOT_ID, ...),
        then the command line, each overriding the one before.

        A YAML file that cannot be read or parsed raises ValueError with the reason.
        """
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        if config_file is not None:
            try:
                loaded = yaml.safe_load(config_file.read_text(encoding="utf-8"))
            except OSError as exc:
                raise ValueError(f"{config_file}: cannot read ({exc.strerror})") from None
            except yaml.YAMLError as exc:
                raise ValueError(f"{config_file}: not valid YAML: {exc}") from None
            if loaded is not None and not isinstance(loaded, dict):
                raise ValueError(f"{config_file}: robot settings must be a YAML mapping")
            values.update(loaded or {})
        for key, var in cls.ENV.items():
            raw = env.get(var)
            if key == "name" and raw is None:
                raw = env.get("ROBOT_ID")
            if raw is not None and raw != "":
                values[key] = split_endpoints(raw) if key == "connect" else raw
        values.update({k: v for k, v in given.items() if v is not None})
        return cls.model_validate(values)


def describe_config_error(error: ValidationError) -> str:
    lines = ["invalid robot configuration:"]
    for item in error.errors(include_url=False):
        where = ".".join(str(p) for p in item["loc"]) or "(top level)"
        var = RobotConfig.ENV.get(str(item["loc"][0])) if item["loc"] else None
        hint = f" (or ${var})" if var else ""
        lines.append(f"  {where}{hint}: {item['msg']}")
    return "\n".join(lines)


@dataclass
class LoopTiming:
    """Control-loop period jitter and deadline misses, over a bounded window of periods."""

    period_ns: int
    ticks: int = 0
    deadline_misses: int = 0
    jitter_ns: deque[int] = field(default_factory=lambda: deque(maxlen=20_000))
    recent_miss_ticks: deque[int] = field(default_factory=lambda: deque(maxlen=10))

    def record(self, period_ns: int, overran: bool) -> None:
        self.ticks += 1
        self.jitter_ns.append(abs(period_ns - self.period_ns))
        if overran:
            self.deadline_misses += 1
            self.recent_miss_ticks.append(self.ticks)

    def jitter_p99_ms(self) -> float | None:
        return float(np.percentile(self.jitter_ns, 99)) / 1e6 if self.jitter_ns else None

    def as_dict(self, p99: float | None = None) -> dict[str, Any]:
        """Counters; pass a p99 computed earlier to keep this cheap inside the loop."""
        return {
            "ticks": self.ticks,
            "deadline_misses": self.deadline_misses,
            "period_jitter_p99_ms": self.jitter_p99_ms() if p99 is None else p99,
            "recent_miss_ticks": list(self.recent_miss_ticks),
        }


class RobotProcess:
    """A robot on the swarm: fabric + firmware + Zenoh glue."""

    def __init__(self, config: RobotConfig) -> None:
        self.config = config
        scenario = load_scenario(config.scenario)
        self.mission = RobotMission.from_scenario(scenario, config.name, load_rule_base(scenario))
        self.fuzzy_parameters: FuzzyParameters | None = (
            FuzzyParameters.load(scenario.fuzzy_parameter_file)
            if scenario.fuzzy_parameter_file is not None
            else FuzzyParameters.table2_defaults()
        )
        self.keys = SwarmKeys(config.swarm)
        sonar_count = self.mission.sonar_count
        self.fabric = Fabric(FabricConfig(n_sonar=sonar_count))
        self.drivers = Drivers.attach(self.fabric.bus, sonar_count)
        self.firmware = Firmware(
            self.mission,
            self.drivers,
            key_from_secret(config.secret),
            swarm_hash=swarm_hash_from_name(config.swarm),
        )
        self.period_ns = round(self.mission.params.control_period_s * NS_PER_S)
        self.timing = LoopTiming(self.period_ns)
        self._sense: deque[tuple[bytes, int]] = deque(maxlen=64)
        self._frames: deque[bytes] = deque(maxlen=1024)
        self._admin = AdminQueue()
        self._wake = threading.Event()
        self.malformed_sense = 0
        self.stop = threading.Event()
        self._last_sense: SenseMessage | None = None
        self._last_sense_mono_ns = 0
        self._lockstep = False
        self._last_tick_served = -1
        self._pending_tick: SenseMessage | None = None
        self._fabric_time_ns = 0
        self._telemetry_period_ns = round(NS_PER_S / config.telemetry_rate_hz)
        self._next_telemetry_ns = 0
        self._telemetry_count = 0
        self._jitter_p99_ms: float | None = None
        self.last_report: TickReport | None = None

    # -- callbacks (zenoh threads): queue and return -------------------------------------

    def _on_sense(self, sample: zenoh.Sample) -> None:
        self._sense.append((sample.payload.to_bytes(), time.monotonic_ns()))
        self._wake.set()

    def _on_frame(self, sample: zenoh.Sample) -> None:
        self._frames.append(sample.payload.to_bytes())
        self._wake.set()

    # -- main loop ------------------------------------------------------------------------

    def run(self) -> int:
        cfg = self.config
        with open_client(cfg.connect, cfg.zenoh_config) as session:
            name = cfg.name
            session.declare_subscriber(self.keys.sense(name), self._on_sense)
            session.declare_subscriber(self.keys.radio_rx(name), self._on_frame)
            session.declare_queryable(self.keys.admin(name, "*"), self._admin.on_query)
            act_pub = session.declare_publisher(self.keys.act(name))
            tx_pub = session.declare_publisher(self.keys.radio_tx(name))
            telemetry_pub = session.declare_publisher(self.keys.telemetry(name))
            token = session.liveliness().declare_token(self.keys.alive("robot", name))
            self.firmware.boot(self._tick_fabric)
            gc.collect()
            gc.freeze()  # boot-time objects leave the collector's work: shorter pauses in the loop
            log.info("robot %s up (%s)", name, "leader" if self.mission.is_leader else "follower")
            next_deadline = time.monotonic_ns()
            last_start = None
            while not self.stop.is_set():
                self._serve_queries()
                message = self._take_sense()
                if message is not None and message.lockstep:
                    self._pending_tick = message
                if self._lockstep:
                    pending = self._pending_tick
                    # Serve a tick once its sense message and the frames it announces are here.
                    if pending is None or len(self._frames) < pending.radio_frames:
                        self._wake.wait(0.05)
                        self._wake.clear()
                        continue
                    self._pending_tick = None
                    self._control(pending.t_ns, pending.tick, act_pub, tx_pub, telemetry_pub)
                    self._last_tick_served = pending.tick
                    continue
                now = time.monotonic_ns()
                if self._last_sense is None:
                    # No world yet, hence no time: the firmware waits (admin queries are served).
                    self._wake.wait(0.05)
                    self._wake.clear()
                    next_deadline = time.monotonic_ns()
                    continue
                if now < next_deadline:
                    self._wake.wait((next_deadline - now) / NS_PER_S)
                    self._wake.clear()
                    continue
                start = time.monotonic_ns()
                sim_now = self._sim_time_ns(start)
                self._control(sim_now, 0, act_pub, tx_pub, telemetry_pub)
                end = time.monotonic_ns()
                if last_start is not None:
                    late = start - next_deadline > self.period_ns
                    self.timing.record(
                        start - last_start, late or end > next_deadline + self.period_ns
                    )
                last_start = start
                next_deadline += self.period_ns
                if end - next_deadline > 5 * self.period_ns:  # fell far behind: resynchronise
                    next_deadline = end + self.period_ns
            token.undeclare()
        return 0

    def _take_sense(self) -> SenseMessage | None:
        """Apply every queued sense message to the pins in order; return the newest.

        In lockstep the world waits for each tick, so only one is ever queued, except just
        after the robot (re)joins, when it may find a tick it was not waited for ahead of the
        one it is: it then answers the newest only.
        """
        newest: SenseMessage | None = None
        while self._sense:
            raw, arrival = self._sense.popleft()
            message = decode_sense(raw)
            if message is None or len(message.encoder_counts) != 4:
                self.malformed_sense += 1
                continue
            if len(message.sonar_echo_times_s) != self.mission.sonar_count:
                self.malformed_sense += 1
                continue
            apply_sense(self.fabric, message)
            self._last_sense = message
            self._last_sense_mono_ns = arrival
            self._lockstep = message.lockstep
            newest = message
        return newest

    def _sim_time_ns(self, mono_now_ns: int) -> int:
        if self._last_sense is None:
            return self._fabric_time_ns + self.period_ns
        return self._last_sense.t_ns + (mono_now_ns - self._last_sense_mono_ns)

    def _tick_fabric(self, dt_ns: int) -> None:
        step = self.config.fabric_step_ns
        while dt_ns > 0:
            slice_ns = min(step, dt_ns)
            self.fabric.tick(slice_ns)
            dt_ns -= slice_ns
        self._fabric_time_ns = self.fabric.now_ns

    def _control(
        self,
        now_ns: int,
        tick: int,
        act_pub: zenoh.Publisher,
        tx_pub: zenoh.Publisher,
        telemetry_pub: zenoh.Publisher,
    ) -> None:
        if now_ns > self._fabric_time_ns:
            self._tick_fabric(now_ns - self._fabric_time_ns)
        while self._frames:
            self.firmware.receive(self._frames.popleft(), now_ns)
        report = self.firmware.control_tick(now_ns)
        self.last_report = report
        frames_sent = 0
        if report.frame is not None:
            tx_pub.put(report.frame)
            frames_sent = 1
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
        if now_ns >= self._next_telemetry_ns:
            self._next_telemetry_ns = now_ns + self._telemetry_period_ns
            self._telemetry_count += 1
            if self._telemetry_count % 20 == 1:  # the percentile is refreshed about once a second
                self._jitter_p99_ms = self.timing.jitter_p99_ms()
            telemetry_pub.put(json.dumps(self.telemetry(now_ns)).encode())

    def telemetry(self, now_ns: int) -> dict[str, Any]:
        report = self.last_report
        est = self.firmware.state.estimator
        out: dict[str, Any] = {
            "robot": self.config.name,
            "t_s": now_ns / NS_PER_S,
            "role": "leader" if self.mission.is_leader else "follower",
            "localised": bool(est.localised),
            "estimate": [float(v) for v in est.pose],
            "frames": self.firmware.decoder.counters.as_dict(),
            "bus_errors": self.drivers.bus_errors,
            "malformed_sense": self.malformed_sense,
            "timing": self.timing.as_dict(self._jitter_p99_ms),
            "sonar_range_m": [
                float(g) if np.isfinite(g) else None for g in self.firmware.sonar_gap_m
            ],
            "sonar_echoes_m": self.firmware.sonar_echo_points_m(),
        }
        if report is not None:
            o = report.outputs
            out.update(
                {
                    "desired": [float(v) for v in o.desired_pose],
                    "error": [float(v) for v in o.error],
                    "delta_k": [float(v) for v in o.delta_k],
                    "kp": [float(v) for v in o.kp],
                    "ki": [float(v) for v in o.ki],
                    "kd": [float(v) for v in o.kd],
                    "repulsion_mps": [float(v) for v in o.repulsion_mps],
                    "wheel_speed_radps": [float(v) for v in o.wheel_speed_radps],
                    "active": bool(o.active),
                }
            )
        return out

    def _params_request(self, payload: bytes) -> dict[str, Any]:
        """Get the fuzzy scheduler's parameters, or replace them with a new parameter file.

        The file (YAML or JSON text) is validated first; a bad one is refused with the reason
        and the running parameters stay.  Queries are served between control ticks, so a new
        scheduler takes effect at the next tick.
        """
        if not payload:
            current = self.fuzzy_parameters
            return {"ok": True, "parameters": None if current is None else current.model_dump()}
        try:
            data = yaml.safe_load(payload.decode("utf-8"))
            parameters = FuzzyParameters.model_validate(data)
        except (UnicodeDecodeError, yaml.YAMLError, ValidationError) as exc:
            return {"ok": False, "error": f"fuzzy parameters refused: {exc}"}
        self.firmware.set_rule_base(parameters.rule_base())
        self.fuzzy_parameters = parameters
        log.info(
            "fuzzy parameters replaced: %d x %d sets",
            len(parameters.error_centres),
            len(parameters.rate_centres),
        )
        return {
            "ok": True,
            "rule_count": len(parameters.error_centres) * len(parameters.rate_centres),
        }

    def _serve_queries(self) -> None:
        self._admin.serve(
            {
                "regs": lambda body: handle_regs_request(self.fabric.bus, body),
                "params": self._params_request,
                "status": lambda _body: {
                    "ok": True,
                    **self.telemetry(self._sim_time_ns(time.monotonic_ns())),
                },
            }
        )

"""The live dashboard: a Zenoh client that streams a running swarm into Rerun.

It subscribes to `truth`, every robot's `telemetry`, the world's run `events` and the liveliness
tokens under `alive/` and never publishes, queries or declares a token, so starting, killing or
restarting it changes nothing in the swarm (DESIGN.md §2: the dashboard must never influence
the swarm). Zenoh callbacks only put the sample on a bounded queue (a full queue drops the
sample and counts it); the main thread parses, turns messages into records (`SwarmScene`) and
logs them on the `sim_time` timeline.  Run events that happened before the dashboard subscribed
(it started late, or was restarted) are read from `<out>/events.jsonl`, the world's record of
the run; an event seen both there and live is logged once.

One Rerun recording goes to two sinks at once: a gRPC server that the web viewer connects to
(it keeps up to `server_memory_limit` of data for viewers that connect late; static data is
never dropped) and `<out>/dashboard.rrd`. A dashboard restarted on the same directory keeps the
previous file as `dashboard-<n>.rrd`. A file cut off by a kill has no footer but stays readable
up to its last flushed chunk: a chunk the kill caught half written is cut off the kept file
(`recording_file.trim_partial_message`), so Rerun's Python reader opens it too.

The session is opened on a helper thread because opening waits for the router: a SIGTERM or
Ctrl-C still stops the dashboard while the swarm is not up.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal
from urllib.parse import quote

import rerun as rr
import zenoh
from pydantic import (
    ConfigDict,
    Field,
    FilePath,
    ValidationError,
    field_validator,
    model_validator,
)

from robot_firmware.net.keys import SwarmKeys, check_name
from robot_firmware.net.messages import (
    MessageDropReason,
    TelemetryMessage,
    TruthMessage,
    parse_message_or_reason,
)
from robot_firmware.net.session import DEFAULT_ENDPOINT, open_client, split_endpoints
from services.dashboard import entities
from services.dashboard.blueprint import default_blueprint
from services.dashboard.recording_file import trim_partial_message
from services.dashboard.scene import SwarmScene, Update
from services.dashboard.viewer_options import (
    LOOPBACK_HOSTS,
    browser_host,
    default_listen_address,
    listen_address,
    server_memory_limit,
)
from services.listen_ports import check_port_free
from swarm_config.credentials import (
    CREDENTIALS_FILE_ENV,
    DASHBOARD,
    CredentialsFile,
    check_identity,
)
from swarm_config.faults import RunEvent
from swarm_config.scenario import DEFAULT_SCENARIO_PATH, Scenario
from swarm_config.settings import Endpoints, LayeredSettings

log = logging.getLogger("swarm.dashboard")

APPLICATION_ID = "swarm-cps"
RECORDING_FILE = "dashboard.rrd"
EVENTS_FILE = "events.jsonl"
"""The world's record of the run's events, one `RunEvent` JSON per line, in the run directory."""


class DashboardConfig(LayeredSettings):
    """Settings of the dashboard: YAML file (`swarm dashboard --config`), then environment,
    then flags, like every process of the swarm (swarm_config/settings.py)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scenario: Path = DEFAULT_SCENARIO_PATH
    swarm: str = "lab"
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT], min_length=1)
    zenoh_config: FilePath | None = None
    host: str = Field(default="127.0.0.1", min_length=1)
    """Host name or address of this machine as the browser reaches it (printed in the URL)."""
    bind: str | None = None
    """The address the gRPC data server listens on; None: the loopback address when `host` is
    this machine, else every interface (viewer_options.default_listen_address)."""
    web_port: int = Field(default=9090, ge=1, le=65535)
    grpc_port: int = Field(default=9876, ge=1, le=65535)
    out_dir: Path | None = None
    """Where dashboard.rrd is written; None streams live only."""
    server_memory_limit: str = "256MiB"
    flush_period_s: float = Field(default=1.0, gt=0.0, le=10.0)
    """How long records gather before they go out as one chunk per entity: fewer, larger
    chunks keep the file, the server's buffer and the browser's work small."""
    queue_size: int = Field(default=20_000, ge=1)
    credentials: CredentialsFile = Field(default=None, validate_default=True, repr=False)
    """The dashboard's router user and password (it may subscribe, nothing else): read from
    the file named by --credentials or $SWARM_CREDENTIALS_FILE."""

    WHAT: ClassVar[str] = "dashboard settings"
    ENV: ClassVar[Mapping[str, str]] = {
        "swarm": "SWARM_NAME",
        "scenario": "SWARM_SCENARIO",
        "connect": "ZENOH_CONNECT",
        "zenoh_config": "ZENOH_CONFIG",
        "credentials": CREDENTIALS_FILE_ENV,
    }
    ENV_PARSERS: ClassVar[Mapping[str, Callable[[str], object]]] = {"connect": split_endpoints}

    @field_validator("swarm")
    @classmethod
    def _key_chunk(cls, value: str) -> str:
        return check_name("swarm", value)

    @field_validator("host")
    @classmethod
    def _browser_host(cls, value: str) -> str:
        return browser_host(value)

    @field_validator("bind")
    @classmethod
    def _listen_address(cls, value: str | None) -> str | None:
        return None if value is None else listen_address(value)

    @property
    def bind_address(self) -> str:
        """Where the data server listens (`bind`, or its default for `host`)."""
        return self.bind if self.bind is not None else default_listen_address(self.host)

    @field_validator("server_memory_limit")
    @classmethod
    def _memory_size(cls, value: str) -> str:
        return server_memory_limit(value)

    @model_validator(mode="after")
    def _credentials_are_the_dashboards(self) -> DashboardConfig:
        check_identity(self.credentials, DASHBOARD, self.swarm)
        return self


def grpc_url(host: str, grpc_port: int) -> str:
    """The data source a viewer connects to: the gRPC server's proxy endpoint."""
    return f"rerun+http://{host}:{grpc_port}/proxy"


def viewer_url(host: str, web_port: int, grpc_port: int) -> str:
    """The page to open: the web viewer with its `?url=` data source filled in."""
    return f"http://{host}:{web_port}/?url={quote(grpc_url(host, grpc_port), safe='')}"


def keep_previous_recording(path: Path) -> Path | None:
    """Move an existing recording aside to the first free `<stem>-<n><suffix>`; return it."""
    if not path.exists():
        return None
    n = 1
    while (kept := path.with_name(f"{path.stem}-{n}{path.suffix}")).exists():
        n += 1
    path.rename(kept)
    return kept


MAX_DRAWN_MAGNITUDE = 3.4e38
"""Rerun keeps positions and scalars as float32: a larger value would overflow."""


def _number_problem(value: object) -> str | None:
    """`non_finite` or `out_of_range` for the first float in `value` (a model dump) that no
    producer sends (their JSON writes NaN as null) and the viewer cannot hold; else None."""
    if isinstance(value, float):
        if not math.isfinite(value):
            return "non_finite"
        return "out_of_range" if abs(value) > MAX_DRAWN_MAGNITUDE else None
    if isinstance(value, dict):
        children: Iterable[object] = value.values()
    elif isinstance(value, list | tuple):
        children = value
    else:
        return None
    for child in children:
        if (problem := _number_problem(child)) is not None:
            return problem
    return None


def parse_run_event(payload: bytes | str) -> RunEvent | str:
    """A run event (fields it does not know are ignored, like every reader's), or why it is
    rejected: `not_json`, `does_not_fit`."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return MessageDropReason.NOT_JSON.value
    if not isinstance(data, dict):
        return MessageDropReason.DOES_NOT_FIT.value
    try:
        return RunEvent.model_validate(
            {k: v for k, v in data.items() if k in RunEvent.model_fields}
        )
    except ValidationError:
        return MessageDropReason.DOES_NOT_FIT.value


def event_identity(event: RunEvent) -> str:
    """The same event, read from events.jsonl or heard live, gives the same string."""
    return event.model_dump_json()


@dataclass(frozen=True)
class _Sample:
    kind: Literal["truth", "telemetry", "event", "liveliness"]
    key: str
    payload: bytes
    alive: bool = True
    received_s: float | None = None
    """Monotonic seconds when the sample arrived (truth: for the real-time factor)."""


class DashboardService:
    def __init__(self, config: DashboardConfig, scenario: Scenario) -> None:
        self.config = config
        self.scenario = scenario
        self.scene = SwarmScene(scenario)
        self.keys = SwarmKeys(config.swarm)
        self.stop = threading.Event()
        self.recording_path = None if config.out_dir is None else config.out_dir / RECORDING_FILE
        self.kept_recording: Path | None = None
        self.kept_recording_cut_bytes = 0
        """Bytes of a half-written chunk cut off the kept recording's end."""
        self.url = viewer_url(config.host, config.web_port, config.grpc_port)
        self._inbox: queue.Queue[_Sample] = queue.Queue(maxsize=config.queue_size)
        self.dropped_samples = 0
        self._session: zenoh.Session | None = None
        self._connect_error: BaseException | None = None
        self._connected = threading.Event()
        self.counts = {"truth": 0, "telemetry": 0, "event": 0, "liveliness": 0, "rejected": 0}
        self._events_seen: set[str] = set()
        self._event_lines_read: set[bytes] = set()
        self.rejected: Counter[str] = Counter()
        """Rejected samples per reason: `not_json`, `does_not_fit` (MessageDropReason),
        `non_finite`, `out_of_range` (a number no producer sends), `missing_robots` (a truth
        sample without every robot of the scenario), `unknown_robot` (telemetry of a robot
        the scenario does not name), `wrong_sender` (telemetry naming another robot than the
        one whose key it came on: the router lets each robot put only on its own),
        `ahead_of_world` (telemetry stamped more than `TELEMETRY_LEAD_MAX_S` past the newest
        truth sample, services/dashboard/scene.py), `nothing_to_draw` (telemetry without an
        estimate or gains)."""

    # -- zenoh callbacks: queue and return ------------------------------------------------

    def _offer(self, sample: _Sample) -> None:
        try:
            self._inbox.put_nowait(sample)
        except queue.Full:
            self.dropped_samples += 1

    def _on_truth(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        self._offer(_Sample("truth", str(sample.key_expr), payload, received_s=time.monotonic()))

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        self._offer(_Sample("telemetry", str(sample.key_expr), sample.payload.to_bytes()))

    def _on_event(self, sample: zenoh.Sample) -> None:
        self._offer(_Sample("event", str(sample.key_expr), sample.payload.to_bytes()))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        alive = sample.kind == zenoh.SampleKind.PUT
        self._offer(_Sample("liveliness", str(sample.key_expr), b"", alive))

    # -- session -------------------------------------------------------------------------

    def _open_session(self) -> None:
        try:
            self._session = open_client(
                self.config.connect, self.config.zenoh_config, self.config.credentials
            )
        except Exception as exc:  # reported by the main thread
            self._connect_error = exc
        self._connected.set()

    def _subscribe(self, session: zenoh.Session) -> None:
        keys = self.keys
        session.declare_subscriber(keys.truth, self._on_truth)
        session.declare_subscriber(keys.telemetry_all, self._on_telemetry)
        session.declare_subscriber(keys.events(), self._on_event)
        session.liveliness().declare_subscriber(
            f"{keys.root}/alive/**", self._on_alive, history=True
        )

    # -- rerun ---------------------------------------------------------------------------

    def _open_recording(self) -> rr.RecordingStream:
        cfg = self.config
        check_port_free(cfg.grpc_port)
        check_port_free(cfg.web_port)
        recording = rr.RecordingStream(
            APPLICATION_ID,
            recording_id=uuid.uuid4(),
            batcher_config=rr.ChunkBatcherConfig(flush_tick=cfg.flush_period_s),
        )
        cors = None if cfg.host in LOOPBACK_HOSTS else [f"http://{cfg.host}:{cfg.web_port}"]
        sinks: list[rr.GrpcServerSink | rr.FileSink] = [
            rr.GrpcServerSink(
                bind_ip=cfg.bind_address,
                port=cfg.grpc_port,
                server_memory_limit=cfg.server_memory_limit,
                cors_allow_origin=cors,
            )
        ]
        if self.recording_path is not None:
            self.recording_path.parent.mkdir(parents=True, exist_ok=True)
            self.kept_recording = keep_previous_recording(self.recording_path)
            if self.kept_recording is not None:
                self.kept_recording_cut_bytes = trim_partial_message(self.kept_recording)
            sinks.append(rr.FileSink(str(self.recording_path)))
        blueprint = default_blueprint(self.scene.map_bounds_m())
        rr.set_sinks(*sinks, default_blueprint=blueprint, recording=recording)
        recording.send_recording_name(f"{cfg.swarm}: {self.scenario.name}")
        rr.serve_web_viewer(
            web_port=cfg.web_port,
            open_browser=False,
            connect_to=grpc_url(cfg.host, cfg.grpc_port),
        )
        return recording

    def _log(self, recording: rr.RecordingStream, update: Update | None) -> None:
        if update is None:
            return
        if update.t_s is not None:
            recording.set_time(entities.TIMELINE, duration=update.t_s)
        for record in update.records:
            recording.log(record.entity_path, *record.archetypes, static=record.static)

    def _handle(self, recording: rr.RecordingStream, sample: _Sample) -> None:
        if sample.kind == "liveliness":
            self.counts["liveliness"] += 1
            role = SwarmKeys.chunk(sample.key, 3)
            name = SwarmKeys.last_chunk(sample.key)
            log.info("%s %s %s", role, name, "joined" if sample.alive else "left")
            self._log(recording, self.scene.on_liveliness(role, name, sample.alive))
            return
        if sample.kind == "event":
            update = self.event_update(sample.payload)
        else:
            sender = SwarmKeys.last_chunk(sample.key) if sample.kind == "telemetry" else None
            update = self.update_for(sample.kind, sample.payload, sample.received_s, sender)
        if isinstance(update, str):
            self.counts["rejected"] += 1
            self.rejected[update] += 1
            if self.counts["rejected"] == 1:
                log.warning("ignoring a %s sample on %s: %s", sample.kind, sample.key, update)
            return
        if update is None:  # an event logged already
            return
        self.counts[sample.kind] += 1
        self._log(recording, update)

    def events_from_file(self) -> list[Update]:
        """The records of every run event in `<out>/events.jsonl` not read before (none
        without an out directory or a file); a line that is not an event is counted as
        rejected, once.  A last line without its newline is still being written: it is read
        next time."""
        if self.config.out_dir is None:
            return []
        try:
            lines = (self.config.out_dir / EVENTS_FILE).read_bytes().splitlines(keepends=True)
        except OSError:
            return []
        updates: list[Update] = []
        for ended_line in lines:
            if not ended_line.endswith(b"\n"):
                break
            line = ended_line.rstrip(b"\r\n")
            if not line.strip() or line in self._event_lines_read:
                continue
            self._event_lines_read.add(line)
            update = self.event_update(line)
            if isinstance(update, str):
                self.counts["rejected"] += 1
                self.rejected[update] += 1
            elif update is not None:
                self.counts["event"] += 1
                updates.append(update)
        return updates

    def event_update(self, payload: bytes) -> Update | str | None:
        """The records one run event makes, why it is rejected (a reason of `rejected`), or
        None when the same event was logged already.  Nothing is logged here."""
        event = parse_run_event(payload)
        if isinstance(event, str):
            return event
        if (problem := _number_problem(event.model_dump())) is not None:
            return problem
        identity = event_identity(event)
        if identity in self._events_seen:
            return None
        self._events_seen.add(identity)
        return self.scene.on_event(event)

    def update_for(
        self,
        kind: Literal["truth", "telemetry"],
        payload: bytes,
        received_s: float | None = None,
        sender: str | None = None,
    ) -> Update | str:
        """The records one truth or telemetry sample makes, or why it is rejected (a reason
        of `rejected`); `received_s`: when a truth sample arrived (monotonic seconds);
        `sender`: the robot whose key a telemetry sample came on (None: not checked).
        Nothing is logged here."""
        if kind == "truth":
            truth = parse_message_or_reason(TruthMessage, payload)
            if isinstance(truth, MessageDropReason):
                return truth.value
            if (problem := _number_problem(truth.model_dump())) is not None:
                return problem
            update = self.scene.on_truth(truth, received_s)
            return "missing_robots" if update is None else update
        telemetry = parse_message_or_reason(TelemetryMessage, payload)
        if isinstance(telemetry, MessageDropReason):
            return telemetry.value
        if (problem := _number_problem(telemetry.model_dump())) is not None:
            return problem
        if sender is not None and telemetry.robot != sender:
            return "wrong_sender"
        update = self.scene.on_telemetry(telemetry)
        if update is None:
            if telemetry.robot not in self.scene.names:
                return "unknown_robot"
            if self.scene.ahead_of_world(telemetry.t_s):
                return "ahead_of_world"
            return "nothing_to_draw"
        return update

    # -- main loop -----------------------------------------------------------------------

    def run(self, on_ready: Callable[[], None] | None = None) -> int:
        """Stream until `stop` is set; 0 on a clean stop, 1 if the session could not open."""
        recording = self._open_recording()
        self._log(recording, self.scene.static_update())
        for update in self.events_from_file():  # a swarm that ran before, or runs without us
            self._log(recording, update)
        if on_ready is not None:
            on_ready()
        threading.Thread(target=self._open_session, name="zenoh-connect", daemon=True).start()
        session: zenoh.Session | None = None
        code = 0
        try:
            while not self.stop.is_set():
                if session is None and self._connected.is_set():
                    if self._connect_error is not None:
                        log.error("cannot open a Zenoh session: %s", self._connect_error)
                        code = 1
                        break
                    session = self._session
                    assert session is not None
                    self._subscribe(session)
                    log.info(
                        "subscribed to swarm %s via %s", self.config.swarm, self.config.connect
                    )
                    for update in self.events_from_file():
                        self._log(recording, update)
                try:
                    sample = self._inbox.get(timeout=0.1)
                except queue.Empty:
                    continue
                self._handle(recording, sample)
                for _ in range(self._inbox.qsize()):
                    self._handle(recording, self._inbox.get_nowait())
        finally:
            if session is not None:
                session.close()
            try:
                recording.flush(timeout_sec=10.0)
                recording.disconnect()
            except RuntimeError as exc:  # Rerun's file sink gave up: a full disk
                log.error(
                    "the recording %s ended early (%s): it holds what was written before",
                    self.recording_path,
                    exc,
                )
                code = code or 1
        log.info(
            "stopped: %d truth, %d telemetry, %d event, %d liveliness samples, %d rejected %s, "
            "%d dropped",
            self.counts["truth"],
            self.counts["telemetry"],
            self.counts["event"],
            self.counts["liveliness"],
            self.counts["rejected"],
            dict(self.rejected),
            self.dropped_samples,
        )
        return code

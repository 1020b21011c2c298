"""What the dashboard reads from the swarm: the world's `truth` and each robot's `telemetry`.

The producers build these JSON payloads in `world/runtime.py` (`WorldProcess._publish_truth`) and
`robot_firmware/runtime.py` (`RobotProcess.telemetry`). The models here validate the fields the
dashboard draws and ignore the rest, so a producer may add fields without breaking the viewer;
a payload that is not JSON or lacks a drawn field is rejected as a whole (`None`).
"""

from __future__ import annotations

import json
from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

Pose = tuple[float, float, float]
"""x_m, y_m, theta_rad."""


class _Lenient(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class RobotTruth(_Lenient):
    pose: Pose
    alive: bool = True


class LinkProfileView(_Lenient):
    latency_ms: float = 0.0
    jitter_ms: float = 0.0


class RadioTruth(_Lenient):
    """The radio medium's counters since the world started."""

    frames: int = 0
    delivered: int = 0
    dropped: int = 0
    delivery_ratio: float | None = None
    latency_p50_ms: float | None = None
    latency_p99_ms: float | None = None
    profile: LinkProfileView = LinkProfileView()


class TruthMessage(_Lenient):
    """`swarm/<swarm>/truth`: ground truth at one simulation instant."""

    t_s: float
    tick: int = 0
    robots: dict[str, RobotTruth]
    reference: Pose
    """The leader's reference pose from the trajectory at t_s."""
    radio: RadioTruth = RadioTruth()


class TelemetryMessage(_Lenient):
    """`swarm/<swarm>/telemetry/<robot>`: what one robot's firmware reports about itself."""

    robot: str
    t_s: float
    role: Literal["leader", "follower"] | None = None
    localised: bool = False
    estimate: Pose | None = None
    desired: Pose | None = None
    kp: tuple[float, float, float] | None = None
    ki: tuple[float, float, float] | None = None
    kd: tuple[float, float, float] | None = None
    """Gains of the redundant PID law (eq. 14) per axis x, y, theta, as the fuzzy scheduler
    (Table 2) sets them; absent before the first control tick."""
    sonar_echoes_m: tuple[tuple[float, float], ...] | None = None
    """Where the robot's last sonar sweep puts echoes, [x_m, y_m] in the world seen from its
    estimated pose, one per transducer that heard one; absent from older producers."""


def parse_truth(payload: bytes) -> TruthMessage | None:
    try:
        return TruthMessage.model_validate(json.loads(payload))
    except (ValueError, UnicodeDecodeError, ValidationError):
        return None


def parse_telemetry(payload: bytes) -> TelemetryMessage | None:
    try:
        return TelemetryMessage.model_validate(json.loads(payload))
    except (ValueError, UnicodeDecodeError, ValidationError):
        return None

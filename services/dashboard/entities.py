"""The dashboard's Rerun entity paths: every path is built here and nowhere else.

map                              static y-up transform (Rerun's 2D views draw y down)
map/obstacles                    obstacle discs (static)
map/obstacles/influence          APF influence distance around each obstacle (static)
map/reference_path               the leader's whole reference trajectory (static)
map/reference                    the leader's reference point now
map/robots/<robot>               one robot on the map: body disc (Points2D: robot colour, grey
                                 when down, label with name and role), heading arrow (Arrows2D),
                                 ring where it should be (Ellipses2D: trajectory or slot, eq. 17)
                                 and its trail, the last seconds of true poses (LineStrips2D)
map/robots/<robot>/estimate      the firmware's own pose estimate (telemetry)
map/robots/<robot>/sonar         the last sonar sweep (telemetry): a ray from the estimated
                                 position to each echo (LineStrips2D) and the echo (Points2D);
                                 empty when no transducer hears anything
errors/leader                    leader tracking error ‖(x, y) − (x_d, y_d)‖ in m and
                                 |θ − θ_d| in rad (paper Fig. 12)
errors/formation                 each follower's formation error ‖p_i − p_i,desired‖ in m (Fig. 13)
gains/<kp|ki|kd>/<robot>         PID gains per axis x, y, θ as the fuzzy scheduler sets them
radio/delivery_ratio             delivered / (delivered + dropped): since the world started, and
                                 over the last second of simulated time
radio/latency_ms/configured      the link profile's latency, and latency + jitter
radio/latency_ms/measured        the world's p50 and p99, when the truth carries them
events                           robots, world and launcher joining and leaving, and every run
                                 event of the world (faults injected or refused, robot down and
                                 up, leader changes, world resumed) at its simulation time
timeline/<kind>                  one marker per run event on its kind's row: the fault timeline
clock/real_time_factor           simulated seconds per wall second over the last 5 s of wall time
                                 (truth arrivals; below 1 when the world holds its time for a
                                 starved robot, world/realtime_guard.py)

Several archetypes share one entity where they are logged together (a robot's body, heading,
ring and trail), so each flush of the recording makes one chunk per entity, not one per layer.
"""

from __future__ import annotations

from typing import Literal

Gain = Literal["kp", "ki", "kd"]

MAP = "map"
OBSTACLES = "map/obstacles"
OBSTACLE_INFLUENCE = "map/obstacles/influence"
REFERENCE_PATH = "map/reference_path"
REFERENCE = "map/reference"

LEADER_ERRORS = "errors/leader"
FORMATION_ERRORS = "errors/formation"

GAINS = "gains"
GAIN_NAMES: tuple[Gain, ...] = ("kp", "ki", "kd")

DELIVERY_RATIO = "radio/delivery_ratio"
LATENCY = "radio/latency_ms"
LATENCY_CONFIGURED = "radio/latency_ms/configured"
LATENCY_MEASURED = "radio/latency_ms/measured"

EVENTS = "events"
REAL_TIME_FACTOR = "clock/real_time_factor"
TIMELINE_MARKERS = "timeline"

TIMELINE = "sim_time"
"""The one timeline: simulated seconds from truth and telemetry `t_s`."""


def robot(name: str) -> str:
    return f"map/robots/{name}"


def estimate(name: str) -> str:
    return f"{robot(name)}/estimate"


def sonar(name: str) -> str:
    return f"{robot(name)}/sonar"


def gain_group(gain: Gain) -> str:
    return f"{GAINS}/{gain}"


def gain(gain: Gain, name: str) -> str:
    return f"{gain_group(gain)}/{name}"


def event_marker(kind: str) -> str:
    return f"{TIMELINE_MARKERS}/{kind}"

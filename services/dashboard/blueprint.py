"""The dashboard's default Rerun layout, readable at a glance.

Left: the swarm map (true poses, heading arrows, trails, desired rings, sonar echoes, the
leader's reference path and reference point, obstacles with their APF influence ring) above a
short event log and the fault timeline (one row per kind of run event: faults injected and
refused, robots down and up, leader changes, world resumed).
Right, top to bottom: the leader's tracking error (paper Fig. 12), the followers' formation
errors (Fig. 13), the PID gains K_P / K_I / K_D in tabs as the fuzzy scheduler moves them, and
the radio's delivery ratio and latency, and the real-time factor (below 1 while the world holds
its time for a starved robot). Every view runs on the `sim_time` timeline.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from services.dashboard import entities
from services.dashboard.scene import EVENT_KINDS

GAIN_TITLES = {"kp": "K_P", "ki": "K_I", "kd": "K_D"}


def default_blueprint(map_bounds_m: tuple[float, float, float, float]) -> rrb.Blueprint:
    """map_bounds_m: x_min, x_max, y_min, y_max of the area to show (world frame, y up)."""
    x_min, x_max, y_min, y_max = map_bounds_m
    # The map entity flips y so that y points up; the view's bounds are in the flipped frame.
    swarm_map = rrb.Spatial2DView(
        origin="/",
        contents=[f"+ /{entities.MAP}/**"],
        name=(
            "Swarm map: true poses, trails, desired rings, sonar echoes "
            "(leader labelled, down = grey)"
        ),
        visual_bounds=rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_max, -y_min]),
    )
    gains = rrb.Tabs(
        *(
            rrb.TimeSeriesView(
                origin=f"/{entities.gain_group(gain)}",
                name=f"{GAIN_TITLES[gain]} per robot and axis (fuzzy-scheduled, eq. 14)",
            )
            for gain in entities.GAIN_NAMES
        ),
        active_tab=0,
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                swarm_map,
                rrb.TextLogView(origin=f"/{entities.EVENTS}", name="Events"),
                rrb.TimeSeriesView(
                    origin=f"/{entities.TIMELINE_MARKERS}",
                    name="Fault timeline: faults and what followed, one row per kind",
                    axis_y=rrb.ScalarAxis(range=(-0.5, len(EVENT_KINDS) - 0.5)),
                ),
                row_shares=[5, 1, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=f"/{entities.LEADER_ERRORS}",
                    name="Leader tracking error (Fig. 12)",
                ),
                rrb.TimeSeriesView(
                    origin=f"/{entities.FORMATION_ERRORS}",
                    name="Follower formation error, m (Fig. 13)",
                ),
                gains,
                rrb.Horizontal(
                    rrb.TimeSeriesView(
                        origin=f"/{entities.DELIVERY_RATIO}",
                        name="Radio delivery ratio",
                        axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
                    ),
                    rrb.TimeSeriesView(origin=f"/{entities.LATENCY}", name="Radio latency, ms"),
                    rrb.TimeSeriesView(
                        origin=f"/{entities.REAL_TIME_FACTOR}",
                        name="Real-time factor (sim s per wall s)",
                        axis_y=rrb.ScalarAxis(range=(0.0, 1.1)),
                    ),
                ),
            ),
            column_shares=[5, 4],
        ),
        rrb.TimePanel(timeline=entities.TIMELINE, state="collapsed"),
        collapse_panels=True,
    )

"""summary.json of a run (swarm sim and the world process): schema in docs/summary-schema.md.

The fitness of eq. 16 (``fitness_snr_db``) is computed from ``mean_abs_error_sum``, the time
average of the summed absolute pose errors over t >= ``metrics.fitness_window_start_s``
(default 0: the whole run), and the rule count, with the weights of the scenario's ``fitness``.

The world process adds `run_events` (`summarise_events`): its events.jsonl summed up (counts
per kind, faults injected, failovers and rejoins with their times).

Only simulated quantities go in, never wall-clock figures, so equal seeds give equal files.
Files are written atomically (temporary file, then rename): a killed process leaves either the
old file or the new one, never half of one.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import get_args

import numpy as np

from swarm_config.atomic_files import write_file_atomically
from swarm_config.faults import EventKind, RunEvent
from swarm_config.scenario import Scenario
from world.metrics import fitness_snr

SUMMARY_SCHEMA_VERSION = 1


def controller_label(fuzzy: bool) -> str:
    return "fuzzy_scheduled_pid" if fuzzy else "fixed_gain_pid"


def build_summary(
    scenario: Scenario,
    metrics: dict[str, object],
    fuzzy: bool,
    rule_count_total: int,
    radio_sent: int,
    radio_delivered: int,
    comparison: dict[str, dict[str, object]] | None = None,
) -> dict[str, object]:
    """The summary dict of one run (metrics as produced by MetricsAccumulator.summaries)."""
    fitness = scenario.fitness
    abs_error = metrics.get("mean_abs_error_sum")
    snr = (
        None
        if abs_error is None
        else round(
            float(
                fitness_snr(
                    float(abs_error),  # type: ignore[arg-type]
                    rule_count_total,
                    fitness.error_weight,
                    fitness.rule_weight,
                )
            ),
            6,
        )
    )
    summary: dict[str, object] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "scenario": scenario.name,
        "seed": scenario.seed,
        "duration_s": scenario.duration_s,
        "robots": list(scenario.robot_names),
        "controller": controller_label(fuzzy),
        "steady_state_start_s": scenario.metrics.steady_state_start_s,
        "fitness_window_start_s": scenario.metrics.fitness_window_start_s,
        **metrics,
        "rule_count_total": rule_count_total if fuzzy else 0,
        "fitness_snr_db": snr,
        "radio": {
            "profile": scenario.radio.profile
            if isinstance(scenario.radio.profile, str)
            else "custom",
            "frames_sent": radio_sent,
            "frames_delivered": radio_delivered,
        },
    }
    if comparison is not None:
        summary["comparison"] = comparison
    return summary


def summarise_events(events: Sequence[RunEvent]) -> dict[str, object]:
    """The `run_events` section of a world's summary.json, from its `events.jsonl`.

    counts per kind (every kind present); faults injected per fault name; each failover (a
    `leader_change`) with the time since the old leader was last seen down (None when it was
    not, e.g. after a partition); each rejoin (`robot_up` after a `robot_down` of that robot)
    with the time it was down."""
    counts = {kind: 0 for kind in get_args(EventKind)}
    injected: dict[str, int] = {}
    down_since: dict[str, float] = {}
    failovers: list[dict[str, object]] = []
    rejoins: list[dict[str, object]] = []
    for event in events:
        counts[event.kind] += 1
        if event.kind == "fault_injected":
            name = str(event.detail.get("fault", {}).get("fault", "?"))
            injected[name] = injected.get(name, 0) + 1
        elif event.kind == "robot_down" and event.subject is not None:
            down_since[event.subject] = event.t_s
        elif event.kind == "robot_up" and event.subject in down_since:
            down_s = down_since.pop(event.subject)
            rejoins.append(
                {
                    "robot": event.subject,
                    "down_t_s": down_s,
                    "up_t_s": event.t_s,
                    "down_for_s": round(event.t_s - down_s, 9),
                }
            )
        elif event.kind == "leader_change":
            old = event.detail.get("from")
            old_down_s = down_since.get(old) if isinstance(old, str) else None
            failovers.append(
                {
                    "t_s": event.t_s,
                    "from": old,
                    "to": event.subject,
                    "term": event.detail.get("term"),
                    "after_leader_down_s": None
                    if old_down_s is None
                    else round(event.t_s - old_down_s, 9),
                }
            )
    return {
        "counts": counts,
        "faults_injected": dict(sorted(injected.items())),
        "failovers": failovers,
        "rejoins": rejoins,
    }


def _clean(value: object) -> object:
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_json_atomically(path: Path, data: object, durable: bool = True) -> None:
    """Write `data` as JSON in one rename (swarm_config/atomic_files.py), so readers never see
    half a file; FileWriteError, the old file untouched, when it cannot be written.

    durable=False skips the fsync: the file still survives a killed process (the page cache
    keeps it), only not a power cut; periodic checkpoints of a live run use that.
    """
    text = json.dumps(_clean(data), indent=2, sort_keys=False, allow_nan=False) + "\n"
    write_file_atomically(path, text.encode("utf-8"), durable=durable)

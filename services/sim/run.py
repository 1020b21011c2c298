"""`swarm sim`: one scenario through the batch simulator, summary.json and the paper's figures.

The scenario's controller runs side by side with its counterpart (fixed-gain PID next to a
fuzzy-scheduled one, or the other way round) in one batch with shared noise, so both see the
same disturbances and the difference between them is the controller's alone.

The batch simulator models no faults: a scenario's `faults:` campaign is run by the world
(`swarm up`, `swarm up --lockstep`), and `swarm sim` says so on stderr before it runs.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.sim.batch import run_batch
from services.sim.figures import FIGURE_NAMES, write_figures
from swarm_config.scenario import Scenario, load_rule_base
from world.summary import build_summary, controller_label, write_json_atomically


@dataclass(frozen=True)
class SimOutputs:
    summary_path: Path
    figure_paths: list[Path]
    summary: dict[str, object]


def fixed_gain_rule_base(like: FuzzyRuleBase) -> FuzzyRuleBase:
    """A scheduler whose every rule outputs ΔK = 0: the gains stay at K₀ (fixed-gain PID)."""
    return FuzzyRuleBase(
        error_centres=like.error_centres,
        rate_centres=like.rate_centres,
        error_set_count=like.error_set_count,
        rate_set_count=like.rate_set_count,
        rule_outputs=np.zeros_like(like.rule_outputs),
    )


def fault_campaign_warning(scenario: Scenario) -> str | None:
    """The line that tells a `swarm sim` user the scenario's fault campaign is not run, or None
    for a scenario without one (before, the faults were dropped without a word and the summary
    showed a healthy formation with `events: []`)."""
    count = len(scenario.faults)
    if count == 0:
        return None
    faults = "1 scheduled fault" if count == 1 else f"{count} scheduled faults"
    return (
        f"warning: the batch simulator does not apply this scenario's faults ({faults}); it "
        "runs without them. `swarm up` (or `swarm up --lockstep`) runs the campaign"
    )


SUMMARY_NAME = "summary.json"


def output_names(figures: bool = True) -> tuple[str, ...]:
    """The files `simulate_scenario` writes in its folder."""
    return (SUMMARY_NAME, *(FIGURE_NAMES if figures else ()))


def simulate_scenario(
    scenario: Scenario, out_dir: Path, compare: bool = True, figures: bool = True
) -> SimOutputs:
    warning = fault_campaign_warning(scenario)
    if warning is not None:
        print(f"swarm sim: {warning}", file=sys.stderr, flush=True)
    params = scenario.controller_params()
    scheduler = load_rule_base(scenario)
    fixed = fixed_gain_rule_base(scheduler)
    own = scheduler if params.fuzzy_enabled else fixed
    batch = [own, fixed if params.fuzzy_enabled else scheduler] if compare else [own]
    result = run_batch(
        scenario,
        batch_size=len(batch),
        rule_base=FuzzyRuleBase.stack(batch),
        controller=params.model_copy(update={"fuzzy_enabled": True}),
        shared_noise=True,
        record_trace=figures,
    )
    rules_total = int(result.rule_count[0])
    delivered = result.radio_delivered.tolist()
    comparison = None
    if compare:
        own_fuzzy = params.fuzzy_enabled
        labels = [controller_label(own_fuzzy), controller_label(not own_fuzzy)]
        comparison = {}
        for b, label in enumerate(labels):
            fuzzy = label == controller_label(True)
            entry = build_summary(
                scenario, result.summaries[b], fuzzy, rules_total, result.radio_sent, delivered[b]
            )
            comparison[label] = {
                k: entry[k]
                for k in (
                    "leader_tracking_rms_m",
                    "leader_heading_rms_rad",
                    "formation_rms_m",
                    "formation_max_m",
                    "min_robot_separation_m",
                    "min_obstacle_clearance_m",
                    "collisions",
                    "mean_abs_error_sum",
                    "fitness_snr_db",
                )
            }
    summary = build_summary(
        scenario,
        result.summaries[0],
        params.fuzzy_enabled,
        rules_total,
        result.radio_sent,
        delivered[0],
        comparison,
    )
    summary_path = out_dir / SUMMARY_NAME
    write_json_atomically(summary_path, summary)
    figure_paths: list[Path] = []
    if figures and result.trace is not None:
        figure_paths = write_figures(scenario, result.trace.arrays(), out_dir)
    return SimOutputs(summary_path=summary_path, figure_paths=figure_paths, summary=summary)

"""Fixed-gain PID, Table 2 and an OFA-tuned scheduler on the tuning and held-out scenarios.

Not a test: prints a table, with the machine and the date. Three controllers, simulated side
by side in one batch per scenario and noise seed (shared noise, so they meet the same
disturbances):

* fixed-gain PID: every rule outputs ΔK = 0, the gains stay at K₀ (no rules, N_i = 0 in eq. 16);
* Table 2 with evenly spaced centres on [-1, 1] (49 rules per robot);
* an OFA-tuned scheduler: the fuzzy parameter file given with ``--tuned``, or, without it, the
  result of a quick OFA run on ``--tune-scenario`` (paper.yaml) at ``--budget`` evaluations of
  ``--duration`` simulated seconds (what ``swarm tune`` does, without the files).

Every scenario is run for its full duration with its own windows; the figures are averaged
over ``--noise-seeds`` seeds (the scenario's seed and the following ones). Columns: rules per
robot K, leader tracking RMS and follower formation RMS over nominal steady-state samples, the
eq. 16 error term (Σ_i |x_e| + |y_e| + |θ_e| averaged over the fitness window, by default the
whole run), the fitness of eq. 16 with the scenario's weights, collisions and minimum obstacle
clearance. The lemniscate scenario
was not used for tuning: it shows whether a tuned scheduler carries over.

    .venv/bin/python bench/controller_table.py [--tuned runs/tune/best_fuzzy.yaml]
        [--scenarios configs/scenarios/paper.yaml configs/scenarios/lemniscate.yaml]
        [--noise-seeds 3] [--budget 400] [--duration 30] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from arguments import non_negative_int, positive_float, positive_int
from machine import machine_lines, machine_record

from robot_firmware.control.fuzzy import FuzzyRuleBase
from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from services.sim.batch import run_batch
from services.sim.run import fixed_gain_rule_base
from services.tuner.fitness import make_objective
from services.tuner.fuzzy_encoding import DIMENSION, to_parameters
from services.tuner.registry import ALGORITHMS
from swarm_config.scenario import Scenario, load_fuzzy_parameters, load_scenario
from world.metrics import FormationLayout, fitness_snr

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Controller:
    label: str
    rule_base: FuzzyRuleBase
    rules_per_robot: int


def tuned_parameters(args: argparse.Namespace) -> tuple[FuzzyParameters, str]:
    """The tuned scheduler and where it came from."""
    if args.tuned is not None:
        return load_fuzzy_parameters(args.tuned), str(args.tuned)
    scenario = load_scenario(args.tune_scenario)
    objective = make_objective(scenario, duration_s=args.duration)
    start = time.perf_counter()
    result = ALGORITHMS["ofa"](objective, DIMENSION, args.budget, args.seed)
    source = (
        f"OFA on {scenario.name}, {args.budget} evaluations of {args.duration:g} s, seed "
        f"{args.seed}: {result.best_fitness_db:.3f} dB ({time.perf_counter() - start:.0f} s)"
    )
    return to_parameters(result.best_x), source


def number(value: object) -> float:
    """A summary figure as float; None (no samples) becomes NaN."""
    return float(value) if isinstance(value, int | float) else float("nan")


def evaluate(
    scenario: Scenario, controllers: list[Controller], seeds: list[int]
) -> dict[str, dict[str, float]]:
    """Mean figures over the noise seeds, per controller label."""
    params = scenario.controller_params().model_copy(update={"fuzzy_enabled": True})
    batch = FuzzyRuleBase.stack([c.rule_base for c in controllers])
    names = scenario.robot_names
    followers = [names[i] for i in FormationLayout.from_scenario(scenario).follower_indices]
    rows: dict[str, list[dict[str, float]]] = {c.label: [] for c in controllers}
    for seed in seeds:
        result = run_batch(
            scenario,
            batch_size=len(controllers),
            rule_base=batch,
            controller=params,
            shared_noise=True,
            seed=seed,
        )
        error_sum = result.metrics.mean_abs_error_sum()
        for b, controller in enumerate(controllers):
            summary = result.summaries[b]
            formation = summary["formation_rms_m"]
            assert isinstance(formation, dict)
            rule_total = controller.rules_per_robot * len(names)
            row = {
                "leader_tracking_rms_m": number(summary["leader_tracking_rms_m"]),
                "error_term": float(error_sum[b]),
                "fitness_db": float(
                    fitness_snr(
                        error_sum[b],
                        rule_total,
                        scenario.fitness.error_weight,
                        scenario.fitness.rule_weight,
                    )
                ),
                "collisions": number(summary["collisions"]),
                "min_obstacle_clearance_m": number(summary["min_obstacle_clearance_m"]),
            }
            for name in followers:
                row[f"formation_rms_m:{name}"] = number(formation.get(name))
            rows[controller.label].append(row)
    return {
        label: {key: float(np.mean([r[key] for r in entries])) for key in entries[0]}
        for label, entries in rows.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuned", type=Path, help="a best_fuzzy.yaml from swarm tune")
    parser.add_argument(
        "--scenarios",
        type=Path,
        nargs="+",
        default=[ROOT / "configs/scenarios/paper.yaml", ROOT / "configs/scenarios/lemniscate.yaml"],
    )
    parser.add_argument("--noise-seeds", type=positive_int, default=3)
    parser.add_argument("--tune-scenario", type=Path, default=ROOT / "configs/scenarios/paper.yaml")
    parser.add_argument(
        "--budget", type=positive_int, default=400, help="OFA evaluations when tuning"
    )
    parser.add_argument(
        "--duration", type=positive_float, default=30.0, help="s per tuning evaluation"
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="OFA seed when tuning")
    parser.add_argument("--json", type=Path, dest="json_path", help="also write the figures here")
    args = parser.parse_args()
    if args.noise_seeds < 1:
        parser.error("--noise-seeds must be at least 1")

    tuned, source = tuned_parameters(args)
    table2 = FuzzyRuleBase.table2()
    controllers = [
        Controller("fixed-gain PID", fixed_gain_rule_base(table2), 0),
        Controller("Table 2, even centres", table2, 49),
        Controller(
            "OFA-tuned",
            tuned.rule_base(),
            len(tuned.error_centres) * len(tuned.rate_centres),
        ),
    ]

    for line in machine_lines():
        print(line)
    print(f"# tuned scheduler: {source}")
    print(
        f"#   error centres {[round(c, 3) for c in tuned.error_centres]}, "
        f"rate centres {[round(c, 3) for c in tuned.rate_centres]}"
    )
    per_scenario: dict[str, dict[str, dict[str, float]]] = {}
    for path in args.scenarios:
        scenario = load_scenario(path)
        seeds = [scenario.seed + k for k in range(args.noise_seeds)]
        start = time.perf_counter()
        figures = evaluate(scenario, controllers, seeds)
        wall_s = time.perf_counter() - start
        followers = [k.split(":", 1)[1] for k in figures[controllers[0].label] if ":" in k]
        print()
        print(
            f"{scenario.name}: {scenario.duration_s:g} s, RMS over t >= "
            f"{scenario.metrics.steady_state_start_s:g} s, eq. 16 over t >= "
            f"{scenario.metrics.fitness_window_start_s:g} s, mean over noise seeds {seeds} "
            f"({wall_s:.0f} s)"
        )
        header = (
            f"{'controller':<23}{'K':>4}{'leader cm':>11}"
            + "".join(f"{name + ' cm':>13}" for name in followers)
            + f"{'error term':>12}{'fitness dB':>12}{'collisions':>12}{'clearance cm':>14}"
        )
        print(header)
        for controller in controllers:
            f = figures[controller.label]
            print(
                f"{controller.label:<23}{controller.rules_per_robot:>4}"
                f"{100 * f['leader_tracking_rms_m']:>11.3f}"
                + "".join(f"{100 * f['formation_rms_m:' + name]:>13.3f}" for name in followers)
                + f"{f['error_term']:>12.4f}{f['fitness_db']:>12.3f}{f['collisions']:>12.2f}"
                f"{100 * f['min_obstacle_clearance_m']:>14.2f}"
            )
        per_scenario[scenario.name] = figures
    print()
    print("K: rules per robot; eq. 16 sums them over the robots (fixed-gain PID has none).")
    if args.json_path is not None:
        record = {
            "machine": machine_record(),
            "tuned_source": source,
            "tuned": tuned.model_dump(exclude_none=True),
            "scenarios": per_scenario,
        }
        args.json_path.parent.mkdir(parents=True, exist_ok=True)
        args.json_path.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json_path}")


if __name__ == "__main__":
    main()

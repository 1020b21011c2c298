"""The `swarm` command line.

Subcommands live in their own functions; argument parsing stays here.  A user mistake (bad
scenario, missing file) prints one clear message and exits with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from world.scenario import ScenarioError, load_scenario

EXIT_USAGE = 2


def _cmd_sim(args: argparse.Namespace) -> int:
    from services.sim.run import simulate_scenario

    scenario = load_scenario(Path(args.scenario))
    updates: dict[str, object] = {}
    if args.seed is not None:
        updates["seed"] = args.seed
    if args.duration is not None:
        updates["duration_s"] = args.duration
    if updates:
        scenario = scenario.model_validate({**scenario.model_dump(), **updates})
    out_dir = Path(args.out)
    outputs = simulate_scenario(
        scenario, out_dir, compare=not args.no_compare, figures=not args.no_figures
    )
    s = outputs.summary
    print(f"scenario {s['scenario']} (seed {s['seed']}, {s['duration_s']} s, {s['controller']})")
    print(
        f"  leader tracking RMS   {_cm(s['leader_tracking_rms_m'])}  (nominal samples, t >= "
        f"{s['steady_state_start_s']} s)"
    )
    formation = s["formation_rms_m"]
    assert isinstance(formation, dict)
    for name, value in formation.items():
        print(f"  formation RMS {name:<7} {_cm(value)}")
    print(
        f"  min obstacle clearance {_cm(s['min_obstacle_clearance_m'])}, "
        f"min robot separation {_cm(s['min_robot_separation_m'])}, collisions {s['collisions']}"
    )
    comparison = s.get("comparison")
    if isinstance(comparison, dict):
        for label, entry in comparison.items():
            print(
                f"  {label:<20} leader {_cm(entry['leader_tracking_rms_m'])}, formation "
                f"{', '.join(_cm(v) for v in entry['formation_rms_m'].values())}, "
                f"fitness (16) {entry['fitness_snr_db']} dB"
            )
    print(f"wrote {outputs.summary_path}")
    for path in outputs.figure_paths:
        print(f"wrote {path}")
    return 0


def _cm(value: object) -> str:
    if value is None:
        return "n/a"
    return f"{100.0 * float(value):.2f} cm"  # type: ignore[arg-type]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm",
        description=(
            "Emulator of a swarm robotic cyber-physical system: leader-follower formation with "
            "fuzzy-scheduled PID, APF obstacle avoidance and OFA tuning."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sim = sub.add_parser(
        "sim",
        help="run a scenario in the in-process batch simulator",
        description=(
            "Run one scenario file in the batch simulator and write DIR/summary.json and the "
            "paper's Figs. 11-13 as PNG. The scenario's controller is run side by side with its "
            "counterpart (fixed-gain vs fuzzy-scheduled PID) under the same noise, and both are "
            "reported. Equal seeds give byte-identical summary.json files."
        ),
    )
    sim.add_argument("--scenario", required=True, metavar="FILE", help="scenario YAML file")
    sim.add_argument("--out", required=True, metavar="DIR", help="output directory")
    sim.add_argument("--seed", type=int, help="override the scenario's seed")
    sim.add_argument("--duration", type=float, metavar="S", help="override duration_s")
    sim.add_argument(
        "--no-compare", action="store_true", help="run only the scenario's own controller"
    )
    sim.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    sim.set_defaults(handler=_cmd_sim)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        code: int = args.handler(args)
    except ScenarioError as exc:
        print(f"swarm {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"swarm {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader of our output went away (e.g. `| head`); nothing left to say.
        sys.stderr.close()
        return 0
    return code


if __name__ == "__main__":
    sys.exit(main())

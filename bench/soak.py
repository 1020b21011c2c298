"""Soak: the real-time swarm under a random fault of the fault API every 30 s.

`swarm up` (real time, no dashboard) runs the paper scenario from a copy whose `duration_s` is
2000 s, so its reference never ends within the soak.  After `--warmup-s` (the formation
gathers), every `--every-s` seconds one *episode* starts: a fault injected with `swarm fault
...` (the command line a user types, so the world's `fault` verb and the command's way round a
world that cannot answer are what is exercised) and, `--hold-s` later, the fault that undoes
it.  The first three episodes are the leader (kill + restart), the world (kill + restart) and
the router (kill + restart); the rest are drawn with `--seed` from: kill + restart of a
follower, stop + cont of any robot or the world, a partition of one robot + heal, loss on every
link + heal, and each register fault + clear_registers.

The bench polls the world's and the launcher's status every `--poll-s` (the sim time, the live
robots, each robot's position error, the collision count, the PIDs) and samples the resident
memory of every process every `--rss-every-s`.  At the end it prints, after the machine header:

* one row per episode: what was injected and undone, how the API answered, the failover time
  (a leader fault: from the injection to the next `leader_change` event, in simulation time,
  from `events.jsonl` or summary.json) and the recovery time (wall seconds from the undo until
  every robot is live with its position error under 5 cm; `-` when that did not happen before
  the next episode);
* the collision count (goal 0), from the world's last status and summary.json, and each
  `collision` event (who touched what, when, in which episode);
* per process, the RSS at its first and its last sample and the growth between them (goal
  < 20 %), and the same for the PID that lived longest (a restarted process starts afresh, and
  is measured from 20 s after it was first seen, once it has loaded its code).

Everything is also written to `<out>/soak.json`.  Make it work short, then long:

    .venv/bin/python bench/soak.py --minutes 3
    .venv/bin/python bench/soak.py            # 30 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml
from arguments import non_negative_int, positive_float
from machine import machine_lines, machine_record
from proc_stats import rss_mib
from swarm_up import OPERATOR_CREDENTIALS, SwarmUp

from swarm_config.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
SOAK_DURATION_S = 2000.0
FORMATION_BOUND_M = 0.05
RSS_GOAL_PERCENT = 20.0
RSS_SETTLE_S = 20.0
"""A process started during the soak is measured from this long after it was first seen."""
RssSample = tuple[float, int, float]
"""wall s, PID, RSS MiB."""


LEADER = "@leader"
"""In an episode's arguments: the robot that leads when the episode starts."""
FOLLOWER = "@follower"
"""In an episode's arguments: a robot that does not lead then (drawn with the seed)."""


@dataclass(frozen=True)
class Episode:
    """One fault and what undoes it, as `swarm fault` arguments (LEADER and FOLLOWER stand for
    whoever leads and follows when it starts: after a failover another robot leads)."""

    name: str
    inject: tuple[str, ...]
    undo: tuple[str, ...] | None


def episode_pool(robots: tuple[str, ...], rng: random.Random) -> list[Episode]:
    """Every kind of episode, its subjects and settings drawn with `rng`."""
    robot = rng.choice(robots)
    wheel = str(rng.randrange(4))
    register = [
        ("pwm-stuck", "--wheel", wheel, "--duty", f"{rng.uniform(-0.6, 0.6):.2f}"),
        ("pwm-saturated", "--wheel", wheel, "--sign", rng.choice(["-1", "1"])),
        ("encoder-stuck", "--wheel", wheel),
        ("encoder-bit-stuck", "--wheel", wheel, "--bit", str(rng.randrange(4, 12)), "--value", "1"),
        ("sonar-no-echo",),
        ("fix-cut",),
        ("watchdog-expire",),
        ("tick-slow", "--extra-ms", f"{rng.uniform(2.0, 8.0):.1f}"),
    ]
    pool = [
        Episode("kill+restart a follower", ("kill", FOLLOWER), ("restart", FOLLOWER)),
        Episode("stop+cont the leader", ("stop", LEADER), ("cont", LEADER)),
        Episode("stop+cont a follower", ("stop", FOLLOWER), ("cont", FOLLOWER)),
        Episode("stop+cont world", ("stop", "world"), ("cont", "world")),
        Episode(f"partition {robot}+heal", ("partition", robot), ("heal",)),
        Episode("net loss 0.3+heal", ("net", "--loss", "0.3"), ("heal",)),
    ]
    for name, *settings in register:
        target = rng.choice(robots)
        pool.append(
            Episode(
                f"{name} {target}+clear",
                (name, target, *settings),
                ("clear-registers", target),
            )
        )
    return pool


def plan_episodes(count: int, robots: tuple[str, ...], rng: random.Random) -> list[Episode]:
    """The leader, the world and the router first, then every kind of episode once in a random
    order (subjects and settings drawn anew each round), round after round."""
    fixed = [
        Episode("kill+restart the leader", ("kill", LEADER), ("restart", LEADER)),
        Episode("kill+restart world", ("kill", "world"), ("restart", "world")),
        Episode("kill+restart router", ("kill", "router"), ("restart", "router")),
    ]
    plan = fixed[:count]
    while len(plan) < count:
        round_ = episode_pool(robots, rng) + fixed
        rng.shuffle(round_)
        plan += round_[: count - len(plan)]
    return plan


@dataclass
class Answer:
    """What `swarm fault ...` said."""

    argv: tuple[str, ...]
    wall_s: float
    sim_t_s: float | None
    exit_code: int
    outcome: str
    via_launcher: bool


@dataclass
class EpisodeRecord:
    episode: Episode
    started_wall_s: float
    inject: tuple[str, ...] = ()
    undo: tuple[str, ...] | None = None
    """The episode's arguments with LEADER and FOLLOWER filled in when it started."""
    leader_fault: bool = False
    """It killed or stopped the robot that led: a failover should follow."""
    injected: Answer | None = None
    undone: Answer | None = None
    failover_s: float | None = None
    recovered_after_s: float | None = None


@dataclass
class Sample:
    wall_s: float
    sim_t_s: float | None
    live: tuple[str, ...]
    errors_m: dict[str, float]
    collisions: int | None


@dataclass
class Soak:
    up: SwarmUp
    robots: tuple[str, ...]
    samples: list[Sample] = field(default_factory=list)
    rss: dict[str, list[RssSample]] = field(default_factory=dict)
    """process -> (wall s, pid, RSS MiB) samples."""
    started_mono_s: float = field(default_factory=time.monotonic)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def wall_s(self) -> float:
        return time.monotonic() - self.started_mono_s

    def sim_time_now(self) -> float | None:
        status = self.up.world_status(timeout_s=1.0)
        return None if status is None else status.t_s

    def fault(self, argv: tuple[str, ...]) -> Answer:
        sim_t_s = self.sim_time_now()
        wall_s = self.wall_s()
        operator = self.up.out / OPERATOR_CREDENTIALS
        result = subprocess.run(
            [sys.executable, "-m", "services.cli.main", "fault", *argv]
            + ["--connect", self.up.endpoint, "--swarm", self.up.swarm]
            + ["--credentials", str(operator)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        return Answer(
            argv,
            wall_s,
            injected_at_s(result) or sim_t_s,
            result.returncode,
            describe_answer(result),
            "asking the launcher" in result.stderr,
        )

    def poll(self) -> None:
        status = self.up.world_status(timeout_s=1.0)
        sample = Sample(
            self.wall_s(),
            None if status is None else status.t_s,
            () if status is None else tuple(status.live),
            {} if status is None else dict(status.position_errors_m),
            None if status is None else status.metrics.collisions,
        )
        with self.lock:
            self.samples.append(sample)

    def sample_rss(self) -> None:
        launcher = self.up.launcher_status(timeout_s=1.0)
        pids = {"launcher": self.up.process.pid}
        if launcher is not None:
            pids.update(
                {name: p.pid for name, p in launcher.processes.items() if p.pid and p.running}
            )
        now = self.wall_s()
        for name, pid in pids.items():
            value = rss_mib(pid)
            if value is not None:
                self.rss.setdefault(name, []).append((now, pid, value))


def injected_at_s(result: subprocess.CompletedProcess[str]) -> float | None:
    """The simulation time the world recorded the fault at (its answer's event), if it
    answered."""
    try:
        reply = json.loads(result.stdout)
        return float(reply["event"]["t_s"])
    except (ValueError, KeyError, TypeError):
        return None


def describe_answer(result: subprocess.CompletedProcess[str]) -> str:
    """ok / refused: reason / the command's error, in a few words."""
    if result.returncode in (0, 1):
        try:
            reply = json.loads(result.stdout)
        except ValueError:
            reply = {}
        if result.returncode == 0:
            return "ok"
        return f"refused: {reply.get('reason', '?')}"
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    return f"error: {lines[-1][:80] if lines else result.returncode}"


def recovered_after(samples: list[Sample], robots: tuple[str, ...], from_wall_s: float,
                    until_wall_s: float) -> float | None:  # fmt: skip
    """Wall seconds from `from_wall_s` to the first sample with every robot live and within
    FORMATION_BOUND_M of its reference, before `until_wall_s`."""
    for sample in samples:
        if not from_wall_s <= sample.wall_s < until_wall_s:
            continue
        in_place = all(
            name in sample.live and sample.errors_m.get(name, 1e9) < FORMATION_BOUND_M
            for name in robots
        )
        if in_place:
            return sample.wall_s - from_wall_s
    return None


def run_events(out: Path) -> list[dict[str, Any]]:
    """The run's events: events.jsonl when the world writes one, plus summary.json's list."""
    events: list[dict[str, Any]] = []
    try:
        for line in (out / "events.jsonl").read_text(encoding="utf-8").splitlines():
            if line.strip():
                events.append(json.loads(line))
    except (OSError, ValueError):
        pass
    try:
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        summary = {}
    listed = summary.get("events")
    if isinstance(listed, list):
        events += [e for e in listed if isinstance(e, dict) and e not in events]
    return events


def acting_leader(events: list[dict[str, Any]], designated: str) -> str:
    """Who leads after the last `leader_change` event (the designated leader before any)."""
    changes = [e for e in events if e.get("kind") == "leader_change" and e.get("subject")]
    return str(changes[-1]["subject"]) if changes else designated


def resolve(argv: tuple[str, ...] | None, leader: str, follower: str) -> tuple[str, ...] | None:
    if argv is None:
        return None
    return tuple(leader if a == LEADER else follower if a == FOLLOWER else a for a in argv)


def failover_after(events: list[dict[str, Any]], injected_sim_s: float | None) -> float | None:
    """Simulation seconds from a leader fault to the next leader_change event."""
    if injected_sim_s is None:
        return None
    changes = sorted(
        float(e["t_s"])
        for e in events
        if e.get("kind") == "leader_change" and float(e.get("t_s", -1)) >= injected_sim_s
    )
    return changes[0] - injected_sim_s if changes else None


def settled(samples: list[RssSample], settle_s: float) -> list[RssSample]:
    """The samples of one PID from `settle_s` after it was first seen on (a process started
    during the soak is still importing at first): all of them for a PID already running at the
    first sample of the soak (it started before the swarm ticked), never fewer than one."""
    if samples[0][0] <= settle_s:
        return samples
    later = [s for s in samples if s[0] >= samples[0][0] + settle_s]
    return later or samples[-1:]


def rss_table(rss: dict[str, list[RssSample]], settle_s: float) -> list[dict[str, Any]]:
    """Per process: RSS at its first and last sample (the first PID's settled first sample, the
    last PID's last) and the growth of the PID that lived longest, from its settled first
    sample to its last."""
    rows = []
    for name, samples in rss.items():
        by_pid: dict[int, list[RssSample]] = {}
        for sample in samples:
            by_pid.setdefault(sample[1], []).append(sample)
        lives = [settled(pid_samples, settle_s) for pid_samples in by_pid.values()]
        first, last = lives[0][0], lives[-1][-1]
        longest = max(lives, key=lambda life: life[-1][0] - life[0][0])
        rows.append(
            {
                "process": name,
                "pids": len(by_pid),
                "rss_first_mib": first[2],
                "rss_last_mib": last[2],
                "growth_percent": 100.0 * (last[2] - first[2]) / first[2],
                "longest_pid_span_s": longest[-1][0] - longest[0][0],
                "longest_pid_growth_percent": 100.0
                * (longest[-1][2] - longest[0][2])
                / longest[0][2],
            }
        )
    return rows


def soak_scenario(out: Path) -> Path:
    data = yaml.safe_load(PAPER.read_text(encoding="utf-8"))
    data["duration_s"] = SOAK_DURATION_S
    data["name"] = "paper-soak"
    path = out / "soak-scenario.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _cell(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def collisions_by_episode(
    events: list[dict[str, Any]], records: list[EpisodeRecord]
) -> list[tuple[float, str, str, str]]:
    """Each `collision` event: (t_s, robot, what it touched, the episode whose injection came
    last before it, by simulation time, or "before the first episode")."""
    starts = [
        (r.injected.sim_t_s, f"episode {i + 1}, {r.episode.name}")
        for i, r in enumerate(records)
        if r.injected is not None and r.injected.sim_t_s is not None
    ]
    found = []
    for event in events:
        if event.get("kind") != "collision":
            continue
        t_s = float(event.get("t_s", 0.0))
        during = [name for start_s, name in starts if start_s <= t_s]
        episode = during[-1] if during else "before the first episode"
        touched = str(event.get("detail", {}).get("with", "?"))
        found.append((t_s, str(event.get("subject")), touched, episode))
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=positive_float, default=30.0)
    parser.add_argument("--every-s", type=positive_float, default=30.0, help="one episode per this")
    parser.add_argument("--hold-s", type=positive_float, default=8.0, help="fault held this long")
    parser.add_argument(
        "--warmup-s",
        type=positive_float,
        default=20.0,
        help="formation time before the first episode",
    )
    parser.add_argument("--seed", type=non_negative_int, default=1)
    parser.add_argument("--poll-s", type=positive_float, default=0.5)
    parser.add_argument("--rss-every-s", type=positive_float, default=10.0)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "soak")
    args = parser.parse_args(argv)
    if args.hold_s >= args.every_s:
        parser.error("--hold-s must be shorter than --every-s")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    scenario_path = soak_scenario(out)
    scenario = load_scenario(scenario_path)
    robots = tuple(scenario.robot_names)
    leader = robots[scenario.leader_index]
    rng = random.Random(args.seed)
    count = max(1, int((args.minutes * 60.0 - args.warmup_s) // args.every_s))
    plan = plan_episodes(count, robots, rng)
    pick = random.Random(args.seed + 1)  # the robot of a FOLLOWER episode, as it starts
    records = [
        EpisodeRecord(e, started_wall_s=args.warmup_s + i * args.every_s)
        for i, e in enumerate(plan)
    ]
    header = machine_lines()
    print("\n".join(header), flush=True)
    print(
        f"# soak: {args.minutes:g} min, {count} episodes, seed {args.seed}, out {out}", flush=True
    )

    up = SwarmUp(out, "--scenario", str(scenario_path))
    try:
        up.wait_ticking(timeout_s=120.0)
        soak = Soak(up, robots)
        stop = threading.Event()

        def injector() -> None:
            for record in records:
                if stop.wait(max(0.0, record.started_wall_s - soak.wall_s())):
                    return
                leads = acting_leader(run_events(out), leader)
                follower = pick.choice([r for r in robots if r != leads])
                inject = resolve(record.episode.inject, leads, follower)
                assert inject is not None
                record.inject, record.undo = inject, resolve(record.episode.undo, leads, follower)
                record.leader_fault = inject[0] in ("kill", "stop") and inject[1] == leads
                record.injected = soak.fault(inject)
                print(f"[{soak.wall_s():7.1f} s] {record.episode.name}: "
                      f"{' '.join(inject)} -> {record.injected.outcome}", flush=True)  # fmt: skip
                if record.undo is None:
                    continue
                if stop.wait(max(0.0, record.started_wall_s + args.hold_s - soak.wall_s())):
                    return
                record.undone = soak.fault(record.undo)
                print(f"[{soak.wall_s():7.1f} s]   undo: {' '.join(record.undo)} -> "
                      f"{record.undone.outcome}", flush=True)  # fmt: skip

        thread = threading.Thread(target=injector, name="soak-injector", daemon=True)
        soak.started_mono_s = time.monotonic()
        thread.start()
        end_s = args.minutes * 60.0
        next_rss_s = 0.0
        while soak.wall_s() < end_s:
            up._check_running()
            soak.poll()
            if soak.wall_s() >= next_rss_s:
                soak.sample_rss()
                next_rss_s += args.rss_every_s
            time.sleep(args.poll_s)
        soak.sample_rss()
        stop.set()
        thread.join(timeout=120.0)
        last = next((s for s in reversed(soak.samples) if s.collisions is not None), None)
    finally:
        up.stop()
    events = run_events(out)
    summary = up.summary() or {}
    for i, record in enumerate(records):
        until_s = records[i + 1].started_wall_s if i + 1 < len(records) else float("inf")
        if record.leader_fault and record.injected is not None:
            record.failover_s = failover_after(events, record.injected.sim_t_s)
        undone_at = record.undone.wall_s if record.undone is not None else None
        if undone_at is not None:
            record.recovered_after_s = recovered_after(soak.samples, robots, undone_at, until_s)
    rss = rss_table(soak.rss, RSS_SETTLE_S)
    collisions_status = None if last is None else last.collisions
    collisions_summary = summary.get("collisions")

    print("\n".join(header))
    print(
        f"# soak: {args.minutes:g} min of `swarm up` in real time (paper scenario, duration_s "
        f"{SOAK_DURATION_S:g}), one episode every {args.every_s:g} s, fault held "
        f"{args.hold_s:g} s, seed {args.seed}"
    )
    print()
    print("| # | at s | episode | injected | undone | failover s (sim) | recovered after s |")
    print("|---|---|---|---|---|---|---|")
    for i, record in enumerate(records):
        injected = record.injected.outcome if record.injected else "not run"
        if record.injected is not None and record.injected.via_launcher:
            injected += " (launcher)"
        undone = record.undone.outcome if record.undone else "-"
        if record.undone is not None and record.undone.via_launcher:
            undone += " (launcher)"
        failover = _cell(record.failover_s, 2) if record.leader_fault else "n/a"
        what = record.episode.name + (f": {' '.join(record.inject)}" if record.inject else "")
        print(
            f"| {i + 1} | {record.started_wall_s:.0f} | {what} | {injected} | "
            f"{undone} | {failover} | {_cell(record.recovered_after_s)} |"
        )
    print()
    print(
        f"collisions: {collisions_status} in the world's last status, {collisions_summary} in "
        "summary.json (goal 0)"
    )
    kinds: dict[str, int] = {}
    for event in events:
        kinds[str(event.get("kind"))] = kinds.get(str(event.get("kind")), 0) + 1
    print(f"events recorded: {kinds or 'none'}")
    collided = collisions_by_episode(events, records)
    for t_s, robot, touched, episode in collided:
        print(f"  collision at t = {t_s:.2f} s: {robot} touched {touched} ({episode})")
    print()
    print("| process | PIDs | RSS first MiB | RSS last MiB | growth % | longest-lived PID: "
          "span s, growth % |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for row in rss:
        print(
            f"| {row['process']} | {row['pids']} | {row['rss_first_mib']:.1f} | "
            f"{row['rss_last_mib']:.1f} | {row['growth_percent']:+.1f} | "
            f"{row['longest_pid_span_s']:.0f}, {row['longest_pid_growth_percent']:+.1f} |"
        )
    worst = max((abs(r["longest_pid_growth_percent"]) for r in rss), default=0.0)
    print(f"largest growth of a PID over its life: {worst:.1f} % (goal < {RSS_GOAL_PERCENT:g} %)")
    result = {
        "machine": machine_record(),
        "arguments": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "episodes": [asdict(r) for r in records],
        "collisions_status": collisions_status,
        "collisions_summary": collisions_summary,
        "event_counts": kinds,
        "collisions": [
            {"t_s": t_s, "robot": robot, "with": touched, "episode": episode}
            for t_s, robot, touched, episode in collided
        ],
        "rss": rss,
        "samples": [asdict(s) for s in soak.samples],
    }
    (out / "soak.json").write_text(json.dumps(result, indent=2, default=str), encoding="utf-8")
    print(f"wrote {out / 'soak.json'}")
    return 0


if __name__ == "__main__":
    os.chdir(ROOT)
    sys.exit(main())

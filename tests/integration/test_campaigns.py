"""Fault campaigns that replay: a scenario's `faults:` schedule, run as real
processes under `swarm up --lockstep`, twice with the same seed, gives byte-identical
summary.json and events.jsonl, and the events are the ones the campaign asks for.

The world executes each entry at the first tick at or after its `at_s` (world/faults.py): a
robot's kill drops its seat at that tick, a restart holds the tick until the new process's token
is seen and joins it there, a restart of the world checkpoints at that tick and resumes from it.
The measured figures are printed.
"""

from __future__ import annotations

import json
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tests.integration.conftest import ROOT, free_ports, run_swarm

pytestmark = pytest.mark.slow

CAMPAIGNS = ROOT / "configs" / "campaigns"
TAKEOVER_WITHIN_S = 1.0


def _run_twice(tmp_path: Path, campaign: str, duration_s: float) -> tuple[dict[str, Any], list]:
    """The campaign twice, both swarms at once (each loads the host for the other, so the two
    runs see different timing: lockstep must not care); asserts the two runs wrote the same
    files, returns the first's."""
    outs = [tmp_path / f"run{k}" for k in (1, 2)]
    ports = dict(zip(outs, free_ports(len(outs)), strict=True))

    def run(out: Path) -> dict[str, Any]:
        return run_swarm(
            out,
            "--lockstep",
            "--scenario",
            str(CAMPAIGNS / f"{campaign}.yaml"),
            "--duration",
            str(duration_s),
            port=ports[out],
        )

    with ThreadPoolExecutor(max_workers=len(outs)) as pool:
        summaries = list(pool.map(run, outs))
    texts = [(out / "events.jsonl").read_text() for out in outs]
    events = [json.loads(line) for line in texts[0].splitlines()]
    print(f"\n{campaign}: {len(events)} events")
    for event in events:
        print(
            f"  t = {event['t_s']:7.3f} s  {event['kind']:<15} {event['subject']} {event['detail']}"
        )
    summary = summaries[0]
    print(
        f"  collisions {summary['collisions']}, min robot separation "
        f"{summary['min_robot_separation_m'] * 100:.2f} cm, radio dropped "
        f"{summary['radio']['dropped']} of {summary['radio']['frames']}, "
        f"run_events {summary['run_events']}"
    )
    assert (outs[0] / "summary.json").read_bytes() == (outs[1] / "summary.json").read_bytes()
    assert texts[0] == texts[1]
    assert summary["duration_s"] == pytest.approx(duration_s)
    counts = summary["run_events"]["counts"]
    assert sum(counts.values()) == len(events)
    return summary, events


def _injected(events: list[dict[str, Any]]) -> list[tuple[float, str, str | None, int]]:
    return [
        (e["t_s"], e["detail"]["fault"]["fault"], e["subject"], e["detail"]["tick"])
        for e in events
        if e["kind"] == "fault_injected"
    ]


def _consequences(events: list[dict[str, Any]]) -> list[tuple[float, str, str | None]]:
    return [
        (e["t_s"], e["kind"], e["subject"])
        for e in events
        if e["kind"] in ("robot_down", "robot_up", "world_resumed")
    ]


def test_world_restart_and_partition_campaign_replays_byte_for_byte(tmp_path: Path) -> None:
    summary, events = _run_twice(tmp_path, "world-restart", 45.0)
    assert _injected(events) == [
        (20.0, "restart", "world", 2000),
        (30.0, "partition", "robot3", 3000),
        (33.0, "heal", None, 3300),
    ]
    assert [e["source"] for e in (x["detail"] for x in events) if "source" in e] == ["schedule"] * 3
    assert not any(e["kind"] == "fault_refused" for e in events)
    # The restarted world resumed at the very tick it was restarted at.
    assert _consequences(events) == [(20.0, "world_resumed", None)]
    assert summary["world_resumes"] == [{"t_s": 20.0, "tick": 2000}]
    # The partition cut robot3's four links for 3 s of 20 Hz broadcasts: 240 frames lost,
    # beside the lab profile's 1 % loss.
    assert summary["radio"]["dropped"] >= 240
    # robot3, cut off, hears nobody: it cannot tell that from being the last one left, so it
    # does not lead (robot_firmware/leadership.py, "Not alone"); it holds still and follows
    # robot1 again after the heal.  Nobody else ever leads, and no two bodies touch.
    assert not any(e["kind"] == "leader_change" for e in events)
    assert summary["collisions"] == 0


def test_follower_kill_and_restart_campaign_replays_byte_for_byte(tmp_path: Path) -> None:
    summary, events = _run_twice(tmp_path, "follower-restart", 40.0)
    assert _injected(events) == [
        (15.0, "kill", "robot3", 1500),
        (25.0, "restart", "robot3", 2500),
    ]
    assert _consequences(events) == [(15.0, "robot_down", "robot3"), (25.0, "robot_up", "robot3")]
    assert [e["detail"]["cause"] for e in events if e["kind"] in ("robot_down", "robot_up")] == [
        "kill",
        "restart",
    ]
    assert not any(e["kind"] in ("leader_change", "fault_refused") for e in events)
    assert summary["run_events"]["rejoins"] == [
        {"robot": "robot3", "down_t_s": 15.0, "up_t_s": 25.0, "down_for_s": 10.0}
    ]
    assert summary["collisions"] == 0


def test_leader_failover_campaign_replays_byte_for_byte(tmp_path: Path) -> None:
    summary, events = _run_twice(tmp_path, "leader-failover", 60.0)
    assert _injected(events) == [(25.0, "kill", "robot1", 2500), (40.0, "restart", "robot1", 4000)]
    assert _consequences(events) == [(25.0, "robot_down", "robot1"), (40.0, "robot_up", "robot1")]
    changes = [e for e in events if e["kind"] == "leader_change"]
    assert [(e["detail"]["from"], e["subject"]) for e in changes] == [("robot1", "robot2")]
    assert 25.0 <= changes[0]["t_s"] <= 25.0 + TAKEOVER_WITHIN_S
    (failover,) = summary["run_events"]["failovers"]
    assert failover["after_leader_down_s"] <= TAKEOVER_WITHIN_S
    assert summary["events"][0]["to"] == "robot2"  # the metrics' own record agrees


def test_a_scenario_edited_during_a_run_changes_nothing_in_it(tmp_path: Path) -> None:
    """A world restarted mid-run reads the run's own copy of its scenario (`scenario.yaml` in the
    run folder), not the file the user typed, which they may have edited since: before, the
    restarted world ran the edited scenario beside robots that ran the original."""
    original = (CAMPAIGNS / "world-restart.yaml").read_text()
    short = original.replace("duration_s: 45.0", "duration_s: 8.0").replace(
        "at_s: 20.0", "at_s: 3.0"
    )
    short = short.split("\n  - at_s: 30.0")[0] + "\n"  # the world's restart only
    assert "at_s: 3.0" in short and "{fault: partition" not in short
    untouched, edited = tmp_path / "untouched.yaml", tmp_path / "edited.yaml"
    untouched.write_text(short)
    edited.write_text(short)
    port_untouched, port_edited = free_ports(2)
    lockstep = ["--lockstep", "--duration", "8"]
    run_swarm(tmp_path / "a", *lockstep, "--scenario", str(untouched), port=port_untouched)
    command = [str(ROOT / "swarm"), "up", *lockstep, "--scenario", str(edited)]
    command += ["--out", str(tmp_path / "b"), "--no-dashboard", "--port", str(port_edited)]
    with subprocess.Popen(command, stdout=subprocess.PIPE, text=True, cwd=ROOT) as swarm:
        assert swarm.stdout is not None
        assert swarm.stdout.readline().startswith("swarm lab:")  # every process started
        # A bigger obstacle, further in: a restarted world reading it would run another run.
        edited.write_text(short.replace("radius_m: 0.15", "radius_m: 0.45"))
        swarm.stdout.read()
        assert swarm.wait(timeout=300) == 0
    first = (tmp_path / "a" / "summary.json").read_bytes()
    assert json.loads(first)["world_resumes"] == [{"t_s": 3.0, "tick": 300}]
    assert (tmp_path / "b" / "summary.json").read_bytes() == first
    assert (tmp_path / "b" / "scenario.yaml").read_text() == short  # copied byte for byte

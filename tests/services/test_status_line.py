"""`swarm status`: the launcher's JSON on stdout, and one line about the world on stderr with
its real-time factor and what it refused from the robots (services/cli/main.py); the world's
reply faked, no network."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pytest

from services.cli import main as cli
from swarm_config.scenario import load_scenario
from world.input_budget import BURST
from world.runtime import WorldConfig, WorldProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def _args() -> argparse.Namespace:
    return argparse.Namespace(timeout=3.0, swarm="lab", connect=None, credentials=None)


def test_the_status_line_shows_the_worlds_real_time_factor(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    world = WorldProcess(WorldConfig(scenario=PAPER), load_scenario(PAPER))
    world._clock_started_mono_s = time.monotonic() - 1.0  # time started a second ago ...
    world.engine.advance(world.duty, 500_000_000)  # ... and 0.5 s of simulation ran
    status = world._status()
    assert status.real_time_factor is not None and status.real_time_factor < 0.51
    asked: list[float] = []

    def answer(
        args: argparse.Namespace, target: str, verb: str, body: object, router_may_be_down: bool
    ) -> bytes:
        asked.append(args.timeout)
        assert (target, verb) == ("world", "status")
        assert router_may_be_down  # the launcher has answered; a router restarting is no error
        return status.to_json_bytes()

    monkeypatch.setattr(cli, "_ask_if_answered", answer)
    cli._print_world_line(_args())
    line = capsys.readouterr().err
    assert asked == [cli.WORLD_STATUS_TIMEOUT_S]
    assert "t = 0.5 s, real time" in line, line
    assert f"real-time factor {status.real_time_factor:.2f} since start" in line, line
    assert "0 of 3 robots live" in line, line


def test_the_status_line_says_so_when_the_world_does_not_answer(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cli, "_ask_if_answered", lambda *_args: None)
    cli._print_world_line(_args())
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.strip() == "world: no answer within 1 s"


def test_the_status_line_names_what_the_world_refused_from_the_robots(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    world = WorldProcess(WorldConfig(scenario=PAPER), load_scenario(PAPER))
    taken = [world._within_budget("frame", "robot2") for _ in range(BURST + 25)]
    assert taken.count(False) == 25  # the clock stood still: the burst, then nothing
    world.spoofed_frames = 3
    status = world._status()
    # The same figures as summary.json's, from the same method.
    summary = world.summary()
    assert status.refused_input.over_budget == summary["over_budget"]
    assert status.refused_input.refused_frames == summary["refused_frames"]
    assert status.refused_input.total() == 28
    monkeypatch.setattr(cli, "_ask_if_answered", lambda *_args: status.to_json_bytes())
    cli._print_world_line(_args())
    line = capsys.readouterr().err
    assert "refused from robots: 3 frames (claimed_another_sender); " in line, line
    assert "frame over budget: robot2 25" in line, line
    assert "robot1" not in line and "robot3" not in line, line


def test_the_status_line_says_none_when_nothing_was_refused(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    world = WorldProcess(WorldConfig(scenario=PAPER), load_scenario(PAPER))
    status = world._status()
    monkeypatch.setattr(cli, "_ask_if_answered", lambda *_args: status.to_json_bytes())
    cli._print_world_line(_args())
    assert capsys.readouterr().err.rstrip().endswith("refused from robots: none")

"""Whether a real-time run held (services/real_time_hold.py), and what `swarm up` says at the end
of a run that did not (services/cli/main.py)."""

from __future__ import annotations

from typing import Any

import pytest

from services.cli.main import _print_real_time_verdict
from services.real_time_hold import (
    HOLD_MISS_SHARE,
    HOLD_REAL_TIME_FACTOR,
    holds_real_time,
    real_time_shortfalls,
)


@pytest.mark.parametrize(
    ("factor", "worst_share", "held"),
    [
        (HOLD_REAL_TIME_FACTOR, HOLD_MISS_SHARE, True),
        (1.0, 0.0, True),
        (0.989, 0.0, False),
        (1.0, 0.0101, False),
        (None, 0.0, False),
        (1.0, None, False),
    ],
)
def test_a_run_holds_only_when_the_world_keeps_up_and_every_robot_keeps_its_deadlines(
    factor: float | None, worst_share: float | None, held: bool
) -> None:
    assert holds_real_time(factor, worst_share) is held


def test_a_run_that_held_has_no_shortfall() -> None:
    assert real_time_shortfalls(0.995, {"robot1": (4, 1000), "robot2": (10, 1000)}) == []


def test_shortfalls_name_the_worlds_pace_and_the_worst_robot() -> None:
    shortfalls = real_time_shortfalls(
        0.884, {"robot1": (5, 1000), "robot2": (18, 1000), "robot3": (11, 1000)}
    )
    assert len(shortfalls) == 2
    assert "0.88 of real time" in shortfalls[0]
    assert "2 of 3 robots" in shortfalls[1]
    assert "worst robot2: 1.8 %" in shortfalls[1]


def test_a_robot_that_never_ticked_is_not_counted() -> None:
    assert real_time_shortfalls(None, {"robot1": (0, 0)}) == []


def _summary(factor: float, misses: dict[str, tuple[int, int]]) -> dict[str, Any]:
    return {
        "clock_mode": "real_time",
        "real_time_factor": factor,
        "control_timing": {
            name: {"deadline_misses": missed, "ticks": ticks}
            for name, (missed, ticks) in misses.items()
        }
        | {"robot9": None},
    }


def test_swarm_up_says_when_a_run_did_not_hold_and_what_to_do(
    capsys: pytest.CaptureFixture[str],
) -> None:
    _print_real_time_verdict(_summary(0.88, {"robot1": (2, 1000), "robot2": (30, 1000)}))
    lines = capsys.readouterr().out.splitlines()
    assert " ".join(lines[0].split()) == "robot1 2 of 1000 control deadlines missed"
    assert " ".join(lines[1].split()) == "robot2 30 of 1000 control deadlines missed"
    assert len(lines) == 3
    assert lines[2].startswith("  did not hold real time: the world ran at 0.88 of real time")
    assert "worst robot2: 3.0 %" in lines[2]
    assert "--lockstep" in lines[2]


def test_swarm_up_adds_nothing_when_a_run_held(capsys: pytest.CaptureFixture[str]) -> None:
    _print_real_time_verdict(_summary(1.0, {"robot1": (0, 500), "robot2": (5, 500)}))
    out = capsys.readouterr().out
    assert "did not hold" not in out
    assert out.count("control deadlines missed") == 2

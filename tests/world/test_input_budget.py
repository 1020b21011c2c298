"""The world's per-robot input budget (world/input_budget.py): a flood is cut to the budget, a
robot that puts what a robot puts is never refused, on either clock."""

from __future__ import annotations

import pytest

from world.input_budget import BURST, PER_PERIOD, InputBudget

PERIOD_NS = 10_000_000
ROBOTS = ("robot1", "robot2")


def test_a_flood_gets_its_burst_then_the_rate_and_nothing_more() -> None:
    budget = InputBudget(ROBOTS, PERIOD_NS)
    taken = sum(budget.take("robot2", 0, 0) for _ in range(10_000))
    assert taken == BURST
    # Ten periods later (on both clocks) it has earned twenty more, not the 10,000 it asks.
    later = 10 * PERIOD_NS
    assert sum(budget.take("robot2", later, later) for _ in range(10_000)) == 10 * PER_PERIOD
    assert budget.refused == {"robot1": 0, "robot2": 20_000 - BURST - 10 * PER_PERIOD}
    # However long it waits, it saves no more than the burst.
    much_later = 10**6 * PERIOD_NS
    assert sum(budget.take("robot2", much_later, much_later) for _ in range(10_000)) == BURST


def test_one_robot_flooding_leaves_the_others_budget_alone() -> None:
    budget = InputBudget(ROBOTS, PERIOD_NS)
    for _ in range(1_000):
        budget.take("robot2", 0, 0)
    assert all(budget.take("robot1", 0, 0) for _ in range(BURST))
    assert budget.refused["robot1"] == 0


@pytest.mark.parametrize("clock", ["simulated", "wall"])
def test_a_robot_at_one_message_per_period_is_never_refused_on_either_clock(clock: str) -> None:
    """Lockstep: simulated time runs, the wall clock may stand (a fast lockstep); real time in
    a safe stop: the wall clock runs while simulated time stands.  Clumps of held-up messages
    (a second's worth at once, as a callback held up for a second finds them) are taken too."""
    budget = InputBudget(ROBOTS, PERIOD_NS)
    t_ns = 0
    for period in range(20_000):
        t_ns += PERIOD_NS
        if 1_000 <= period % 2_000 < 1_099:
            continue  # held up: the messages of these periods come with the next one
        messages = 100 if period % 2_000 == 1_099 else 1
        for _ in range(messages):
            sim_ns, wall_ns = (t_ns, 0) if clock == "simulated" else (0, t_ns)
            assert budget.take("robot1", sim_ns, wall_ns)
    assert budget.refused["robot1"] == 0


def test_clocks_that_go_back_earn_nothing() -> None:
    budget = InputBudget(ROBOTS, PERIOD_NS)
    start = 10**12
    for _ in range(BURST):
        assert budget.take("robot2", start, start)
    assert not budget.take("robot2", 0, 0)  # earlier on both clocks: no credit for that
    assert budget.take("robot2", start + PERIOD_NS, start)  # a period on, on one clock
    assert budget.take("robot2", start + PERIOD_NS, start)
    assert not budget.take("robot2", start + PERIOD_NS, start)


def test_a_name_outside_the_swarm_is_left_to_the_caller() -> None:
    budget = InputBudget(ROBOTS, PERIOD_NS)
    assert all(budget.take("robot9", 0, 0) for _ in range(1_000))
    assert "robot9" not in budget.refused


def test_a_budget_that_cannot_work_is_refused() -> None:
    with pytest.raises(ValueError, match="positive period"):
        InputBudget(ROBOTS, 0)
    with pytest.raises(ValueError, match="burst of at least the rate"):
        InputBudget(ROBOTS, PERIOD_NS, per_period=4, burst=2)

"""wait_for: the value it returns, how often it asks, and what its time-out says."""

from __future__ import annotations

import pytest

from tests.support.fake_clock import FakeClock
from tests.support.waiting import describe_predicate, wait_for


def test_returns_the_first_truthy_value() -> None:
    clock = FakeClock()
    answers = iter([None, {}, 0, {"tick": 7}, {"tick": 8}])
    value = wait_for(lambda: next(answers), 10.0, 0.5, clock=clock, sleep=clock.sleep)
    assert value == {"tick": 7}
    assert clock.sleeps_s == [0.5, 0.5, 0.5]


def test_a_condition_already_true_needs_no_sleep() -> None:
    clock = FakeClock()
    assert wait_for(lambda: "ready", 0.0, 0.5, clock=clock, sleep=clock.sleep) == "ready"
    assert clock.sleeps_s == []


def test_time_out_names_the_condition_and_the_last_value() -> None:
    clock = FakeClock()
    calls: list[float] = []

    def count() -> int:
        calls.append(clock())
        return 0

    with pytest.raises(AssertionError) as raised:
        wait_for(count, 2.0, 0.75, describe="three robots live", clock=clock, sleep=clock.sleep)
    assert str(raised.value) == "three robots live: not met within 2 s; last value 0"
    # Asked at the start, every 0.75 s, and once more at the deadline.
    assert calls == [100.0, 100.75, 101.5, 102.0]


def test_time_out_without_a_description_quotes_the_lambda() -> None:
    clock = FakeClock()
    live: list[str] = ["robot1"]
    with pytest.raises(AssertionError, match=r'"robot3" in live.*last value False'):
        wait_for(lambda: "robot3" in live, 1.0, 0.5, clock=clock, sleep=clock.sleep)


def test_a_named_function_is_described_by_its_name() -> None:
    def summary_written() -> bool:
        return False

    assert describe_predicate(summary_written).endswith("summary_written")


class RefusedReply:
    """Falsy, with a long repr: an answer that is not yet what the test waits for."""

    def __bool__(self) -> bool:
        return False

    def __repr__(self) -> str:
        return "RefusedReply(" + "x" * 5000 + ")"


def test_a_long_last_value_is_cut() -> None:
    clock = FakeClock()
    with pytest.raises(AssertionError) as raised:
        wait_for(RefusedReply, 0.0, describe="accepted", clock=clock, sleep=clock.sleep)
    message = str(raised.value)
    assert message.startswith("accepted: not met within 0 s; last value RefusedReply(xxx")
    assert message.endswith("...")
    assert len(message) < 1100


def test_an_exception_of_the_predicate_propagates() -> None:
    def broken() -> bool:
        raise KeyError("live")

    with pytest.raises(KeyError):
        wait_for(broken, 5.0)


@pytest.mark.parametrize(("timeout_s", "every_s"), [(-1.0, 0.5), (1.0, 0.0)])
def test_bad_timing_is_refused(timeout_s: float, every_s: float) -> None:
    with pytest.raises(ValueError, match="wait_for needs"):
        wait_for(lambda: True, timeout_s, every_s)


def test_the_real_clock_times_out() -> None:
    with pytest.raises(AssertionError, match=r"never: not met within 0\.05 s; last value None"):
        wait_for(lambda: None, 0.05, 0.01, describe="never")

"""The world's files that cannot be written: counted, logged once a streak, then whole again."""

import logging
from pathlib import Path

import pytest

from swarm_config.faults import RunEvent
from world.checkpoint import CheckpointStore, CheckpointWriter
from world.faults import EventLog
from world.write_failures import WriteFailures


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def _messages(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [record.getMessage() for record in caplog.records]


def test_a_streak_of_failures_is_logged_once_then_at_most_once_a_minute(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = FakeClock()
    failures = WriteFailures("summary.json", logging.getLogger("test.writes"), 60.0, clock)
    full = OSError(28, "No space left on device")
    with caplog.at_level(logging.WARNING, logger="test.writes"):
        for _ in range(10):
            failures.failed(full)
            clock.now_s += 5.0
        assert _messages(caplog) == [
            "summary.json not written: [Errno 28] No space left on device; the run goes on"
        ]
        clock.now_s += 20.0  # 65 s after the first line
        failures.failed(full)
        failures.failed(full)
        failures.succeeded()
        failures.succeeded()
    assert _messages(caplog)[1:] == [
        "summary.json still not written: 10 more failures since ([Errno 28] No space left on "
        "device)",
        "summary.json written again after 12 failures",
    ]
    assert failures.failures == 12 and not failures.failing


def _event(t_s: float) -> RunEvent:
    return RunEvent(t_s=t_s, kind="robot_down", subject="robot3", detail={})


def test_events_that_could_not_be_written_are_in_the_file_once_it_can_be(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    path.mkdir()  # the file cannot be opened: every write fails, as on a full disk
    events = EventLog(path)
    events.start(None)
    events.append(_event(1.0))
    events.append(_event(2.0))
    assert events.write_failures.failures == 3 and events.count == 2
    path.rmdir()
    events.append(_event(3.0))
    events.append(_event(4.0))
    lines = path.read_text().splitlines()
    assert [RunEvent.model_validate_json(line).t_s for line in lines] == [1.0, 2.0, 3.0, 4.0]
    assert not events.write_failures.failing and events.write_failures.failures == 3


def test_the_checkpoint_writer_counts_its_failures_and_goes_on(tmp_path: Path) -> None:
    folder = tmp_path / "checkpoints"
    folder.write_text("a file where the folder should be")
    writer = CheckpointWriter(CheckpointStore(folder))
    writer.submit(50, {"tick": 50})
    writer.flush()
    writer.submit(100, {"tick": 100})
    writer.flush()
    assert writer.write_failures.failures == 2 and writer.written == 0
    folder.unlink()
    writer.submit(150, {"tick": 150})
    writer.close()
    assert writer.written == 1 and not writer.write_failures.failing
    assert [tick for tick, _path in CheckpointStore(folder).paths()] == [150]

"""World checkpoints: a restored engine continues bit for bit; a bad file is refused."""

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swarm_config.credentials import CredentialSet, generate_credential_set
from swarm_config.scenario import load_scenario
from world.checkpoint import (
    CheckpointError,
    CheckpointStore,
    CheckpointWriter,
    decode_checkpoint,
    encode_checkpoint,
    write_bytes_atomically,
)
from world.engine import WorldEngine
from world.lockstep import LockstepBarrier
from world.runtime import WorldConfig, WorldProcess

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
PERIOD_NS = 10_000_000


def _engine() -> WorldEngine:
    scenario = load_scenario(PAPER)
    radio = scenario.radio.model_copy(update={"profile": "bursty"})
    return WorldEngine(scenario.model_copy(update={"radio": radio}))


def _run(engine: WorldEngine, first_tick: int, ticks: int) -> list[object]:
    """Lockstep ticks as the world process runs them: sense, frames in, physics; what the
    robots would have seen, for comparison."""
    seen: list[object] = []
    for k in range(first_tick, first_tick + ticks):
        for message in engine.sense():
            seen.append((message.encoder_counts, message.sonar_echo_times_s, message.fix))
        seen.append(engine.due_frames())
        if k % 5 == 0:
            for sender in range(engine.robot_count):
                engine.transmit(sender, f"{sender}:{k}".encode())
        phase = 0.01 * k + np.arange(engine.robot_count * 4).reshape(-1, 4)
        engine.advance(0.6 * np.sin(phase), PERIOD_NS)
    return seen


def test_restored_engine_continues_bit_for_bit() -> None:
    straight = _engine()
    seen_straight = _run(straight, 0, 250)

    first = _engine()
    seen = _run(first, 0, 130)
    raw = encode_checkpoint(first.checkpoint_state())
    resumed = _engine()
    resumed.restore_checkpoint(decode_checkpoint(raw))
    seen += _run(resumed, 130, 120)

    assert seen == seen_straight
    assert resumed.checkpoint_state() == straight.checkpoint_state()
    assert resumed.summary() == straight.summary()
    assert resumed.radio.sent == straight.radio.sent > 0
    assert resumed.t_ns == straight.t_ns == 250 * PERIOD_NS


def test_restore_changes_the_link_profile_and_counters() -> None:
    engine = _engine()
    _run(engine, 0, 40)
    state = engine.checkpoint_state()
    fresh = WorldEngine(load_scenario(PAPER))
    assert fresh.link != engine.link
    fresh.restore_checkpoint(decode_checkpoint(encode_checkpoint(state)))
    assert fresh.link == engine.link
    assert fresh.radio.sent == engine.radio.sent
    assert list(fresh.radio.latencies_ns) == list(engine.radio.latencies_ns)


def test_checkpoint_of_another_scenario_is_refused_and_changes_nothing() -> None:
    engine = _engine()
    _run(engine, 0, 10)
    state = engine.checkpoint_state()
    state["robots"] = ["robot1", "robot2"]
    fresh = _engine()
    before = fresh.checkpoint_state()
    with pytest.raises(CheckpointError, match="robots"):
        fresh.restore_checkpoint(state)
    assert fresh.checkpoint_state() == before


def test_lockstep_barrier_resumes_at_the_tick_with_no_robot_live() -> None:
    barrier = LockstepBarrier(["robot1", "robot2"])
    for name in barrier.names:
        barrier.join(name)
    barrier.start()
    for _ in range(7):
        barrier.advance()
    resumed = LockstepBarrier(barrier.names)
    resumed.resume(json.loads(json.dumps(barrier.export_state())))
    assert resumed.tick == 7
    assert resumed.live() == frozenset()
    assert resumed.complete()
    resumed.join("robot1")
    resumed.start()
    assert resumed.waiting() == {"robot1"}


def _store_with_two(tmp_path: Path) -> tuple[CheckpointStore, list[Path]]:
    store = CheckpointStore(tmp_path / "checkpoints")
    paths = [store.save(tick, {"tick": tick, "pose": [tick, 0.5]}) for tick in (100, 200, 300)]
    return store, paths


def test_store_keeps_the_newest_two(tmp_path: Path) -> None:
    store, paths = _store_with_two(tmp_path)
    assert [tick for tick, _ in store.paths()] == [300, 200]
    assert not paths[0].exists()
    loaded = store.load_latest()
    assert loaded is not None and loaded.tick == 300 and loaded.state["tick"] == 300


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:-7])


def _flip_a_bit(path: Path) -> None:
    raw = bytearray(path.read_bytes())
    raw[-5] ^= 0x04
    path.write_bytes(bytes(raw))


def _wrong_version(path: Path) -> None:
    head, _, body = path.read_bytes().partition(b"\n")
    header = json.loads(head)
    header["version"] = 99
    path.write_bytes(json.dumps(header).encode() + b"\n" + body)


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (_truncate, "truncated"),
        (_flip_a_bit, "checksum mismatch"),
        (_wrong_version, "version 99"),
        (lambda path: path.write_bytes(b""), "no header"),
    ],
)
def test_damaged_checkpoint_is_refused_and_the_previous_used(
    tmp_path: Path, damage: object, reason: str, caplog: pytest.LogCaptureFixture
) -> None:
    store, paths = _store_with_two(tmp_path)
    damage(paths[2])  # type: ignore[operator]
    with pytest.raises(CheckpointError, match=reason):
        decode_checkpoint(paths[2].read_bytes())
    with caplog.at_level(logging.ERROR, logger="swarm.world.checkpoint"):
        loaded = store.load_latest()
    assert loaded is not None and loaded.tick == 200 and loaded.state["tick"] == 200
    assert any("world-000000000300.ckpt refused" in r.getMessage() for r in caplog.records)
    assert any(reason in r.getMessage() for r in caplog.records)
    assert paths[2].with_name(paths[2].name + ".refused").exists()
    # Set aside, the refused file no longer sorts above the checkpoints written after it.
    store.save(250, {"tick": 250})
    assert [tick for tick, _ in store.paths()] == [250, 200]


def test_kill_mid_write_leaves_the_old_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store, paths = _store_with_two(tmp_path)
    before = paths[2].read_bytes()

    def killed(fd: int) -> None:
        raise KeyboardInterrupt  # the process dies between writing and renaming

    monkeypatch.setattr(os, "fsync", killed)
    with pytest.raises(KeyboardInterrupt):
        write_bytes_atomically(paths[2], b"half a checkpoint")
    monkeypatch.undo()
    assert paths[2].read_bytes() == before
    assert [p.name for p in store.directory.iterdir() if p.name.startswith(".")] == []
    loaded = store.load_latest()
    assert loaded is not None and loaded.tick == 300


def test_arrays_of_other_dtypes_are_refused() -> None:
    raw = encode_checkpoint({"a": {"dtype": "|O", "shape": [1], "b64": ""}})
    engine = _engine()
    state = engine.checkpoint_state()
    state["link_bad"] = decode_checkpoint(raw)["a"]
    with pytest.raises(CheckpointError, match="dtype"):
        _engine().restore_checkpoint(state)


def _world(out_dir: Path) -> WorldProcess:
    config = WorldConfig(scenario=PAPER, out_dir=out_dir, lockstep=True)
    return WorldProcess(config, load_scenario(PAPER))


def test_restarted_world_process_resumes_from_the_newest_valid_checkpoint(
    tmp_path: Path,
) -> None:
    world = _world(tmp_path)
    assert world.resumed_from is None and world.tick == 0 and world.engine.t_ns == 0
    store = world.checkpoints
    assert store is not None
    saved = {}
    for _ in range(2):
        _run(world.engine, world.tick, 50)
        for _ in range(50):
            world.barrier.advance()
        world.spoofed_frames += 3
        store.save(world.tick, world.checkpoint_state())
        saved[world.tick] = world.engine.checkpoint_state()

    restarted = _world(tmp_path)
    assert restarted.resumed_from is not None
    assert restarted.tick == 100 and restarted.engine.t_ns == 100 * PERIOD_NS
    assert restarted.engine.checkpoint_state() == saved[100]
    assert restarted.spoofed_frames == 6
    assert restarted.summary()["world_resumes"] == [{"t_s": 1.0, "tick": 100}]

    _flip_a_bit(store.paths()[0][1])
    again = _world(tmp_path)
    assert again.tick == 50 and again.engine.checkpoint_state() == saved[50]
    assert again.spoofed_frames == 3
    assert again.resumes == [{"t_s": 0.5, "tick": 50}]
    assert again.epoch not in (0, restarted.epoch)


def test_writer_thread_writes_the_newest_state_submitted(tmp_path: Path) -> None:
    store = CheckpointStore(tmp_path / "checkpoints")
    writer = CheckpointWriter(store)
    for tick in range(1, 30):
        writer.submit(tick, {"tick": tick})
    writer.close()
    loaded = store.load_latest()
    assert loaded is not None and loaded.tick == 29 and loaded.state == {"tick": 29}
    assert 1 <= writer.written <= 29 and writer.write_failures.failures == 0
    assert len(store.paths()) <= 2


_WRITER_LOOP = """
import sys
from pathlib import Path
from world.checkpoint import CheckpointStore
store = CheckpointStore(Path(sys.argv[1]))
tick = 0
while True:
    tick += 1
    store.save(tick, {"tick": tick, "padding": "x" * 200_000})
    if tick == 3:
        print("writing", flush=True)
"""


def test_a_process_killed_while_writing_leaves_a_valid_checkpoint(tmp_path: Path) -> None:
    directory = tmp_path / "checkpoints"
    for delay_s in (0.0, 0.013, 0.029, 0.051):
        writer = subprocess.Popen(
            [sys.executable, "-c", _WRITER_LOOP, str(directory)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert writer.stdout is not None and writer.stdout.readline() == "writing\n"
        time.sleep(delay_s)
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=30)
        writer.stdout.close()
        loaded = CheckpointStore(directory).load_latest()
        assert loaded is not None and loaded.state["tick"] == loaded.tick >= 3
        assert not list(directory.glob("*.refused"))
        assert not list(directory.glob(".world-*"))  # a killed write's temporary file


def test_clearing_a_store_leaves_its_next_world_nothing_to_resume(tmp_path: Path) -> None:
    store = CheckpointStore(tmp_path / "checkpoints")
    assert store.clear() == 0  # no folder yet
    store.save(50, {"tick": 50})
    store.save(100, {"tick": 100})
    (store.directory / "world-000000000010.ckpt.refused").write_bytes(b"x")
    (store.directory / ".world-000000000150.ckpt.abc").write_bytes(b"half")
    (store.directory / "notes.txt").write_text("the user's")
    assert store.clear() == 2
    assert store.load_latest() is None
    assert sorted(p.name for p in store.directory.iterdir()) == ["notes.txt"]


def test_a_world_resumes_only_from_its_own_runs_checkpoints(tmp_path: Path) -> None:
    """A checkpoint names its run (the run id of the world's credentials, new for every `swarm
    up` and `docker compose up`): a world of another run in the same folder starts afresh
    and removes it, where it used to carry on from the earlier run's end."""
    runs = generate_credential_set("lab", ("robot1", "robot2", "robot3"))

    def world(credentials: CredentialSet) -> WorldProcess:
        config = WorldConfig(
            scenario=PAPER,
            out_dir=tmp_path,
            lockstep=True,
            credentials=credentials.for_identity("world"),
        )
        return WorldProcess(config, load_scenario(PAPER))

    first = world(runs)
    _run(first.engine, first.tick, 50)
    for _ in range(50):
        first.barrier.advance()
    assert first.checkpoints is not None
    first.checkpoints.save(first.tick, first.checkpoint_state())
    assert world(runs).tick == 50  # the same run: a restart resumes
    other = world(runs.with_new_run_id())
    assert other.resumed_from is None and other.tick == 0 and other.engine.t_ns == 0
    assert first.checkpoints.paths() == []  # the earlier run's checkpoint is gone

"""The compiled batch tick loop equals its numpy statement, tick by tick (tests/world/oracle.py).

The loop draws each chunk's random numbers in bulk; a numpy generator's bulk draw equals the
same draws made one tick at a time, which is what keeps the streams those of the tick-by-tick
form.  Chunk boundaries change nothing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import services.sim.batch as batch_module
from robot_firmware.control.fuzzy import FuzzyRuleBase
from services.sim.batch import BatchResult, run_batch
from swarm_config.radio import PROFILES
from swarm_config.scenario import Scenario, load_scenario
from tests.world.oracle import run_batch_oracle

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "configs" / "scenarios"
TRACED = ("true_pose", "estimated_pose", "desired_pose", "errors", "delta_k", "kp")


def _bursty_lemniscate() -> Scenario:
    scenario = load_scenario(SCENARIOS / "lemniscate.yaml")
    link = PROFILES["bursty"].model_copy(update={"range_m": 3.2})
    radio = scenario.radio.model_copy(update={"profile": link})
    return scenario.model_copy(update={"radio": radio})


def _assert_same_run(got: BatchResult, want: BatchResult, atol: float) -> None:
    assert got.trace is not None and want.trace is not None
    a, b = got.trace.arrays(), want.trace.arrays()
    np.testing.assert_array_equal(a["t_s"], b["t_s"])
    np.testing.assert_array_equal(a["trajectory_pose"], b["trajectory_pose"])
    for name in TRACED:
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=atol, err_msg=name)
    assert got.radio_sent == want.radio_sent
    np.testing.assert_array_equal(got.radio_delivered, want.radio_delivered)
    np.testing.assert_array_equal(got.metrics.collisions, want.metrics.collisions)
    for g, w in zip(got.summaries, want.summaries, strict=True):
        for key in ("leader_tracking_rms_m", "mean_abs_error_sum", "min_robot_separation_m"):
            assert g[key] == pytest.approx(w[key], abs=1e-9), key


@pytest.mark.parametrize(
    ("scenario", "options"),
    [
        ("paper", {"batch_size": 1}),
        ("paper", {"batch_size": 2}),
        (
            "paper",
            {
                "batch_size": 3,
                "shared_noise": True,
                "rule_base": FuzzyRuleBase.stack(
                    [FuzzyRuleBase.table2(), FuzzyRuleBase.table2(3, 3), FuzzyRuleBase.table2()]
                ),
            },
        ),
        ("bursty", {"batch_size": 2, "physics_substeps": 2}),
    ],
)
def test_compiled_loop_equals_the_numpy_loop(scenario: str, options: dict[str, object]) -> None:
    world = (
        _bursty_lemniscate() if scenario == "bursty" else load_scenario(SCENARIOS / "paper.yaml")
    )
    got = run_batch(world, duration_s=2.5, record_trace=True, **options)  # type: ignore[arg-type]
    want = run_batch_oracle(world, duration_s=2.5, record_trace=True, **options)  # type: ignore[arg-type]
    _assert_same_run(got, want, atol=1e-9)
    assert int(got.radio_delivered.min()) > 0


def test_chunks_of_ticks_change_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    scenario = _bursty_lemniscate()
    whole = run_batch(scenario, 2, duration_s=1.5, record_trace=True, physics_substeps=2)
    monkeypatch.setattr(batch_module, "CHUNK_VALUES", 1000)  # a few ticks per chunk
    chunked = run_batch(scenario, 2, duration_s=1.5, record_trace=True, physics_substeps=2)
    _assert_same_run(chunked, whole, atol=0.0)
    assert chunked.summaries == whole.summaries


def test_bulk_draws_equal_draws_tick_by_tick() -> None:
    bulk, single = np.random.default_rng(3), np.random.default_rng(3)
    normals = bulk.standard_normal((7, 2, 3, 4))
    uniforms = bulk.random(30)
    np.testing.assert_array_equal(normals, [single.standard_normal((2, 3, 4)) for _ in range(7)])
    np.testing.assert_array_equal(
        uniforms, np.concatenate([single.random((2, 3)).ravel() for _ in range(5)])
    )


def test_same_seed_same_batch_and_bad_arguments_are_refused() -> None:
    scenario = load_scenario(SCENARIOS / "paper.yaml")
    first = run_batch(scenario, 2, duration_s=1.0, seed=5)
    again = run_batch(scenario, 2, duration_s=1.0, seed=5)
    assert first.summaries == again.summaries
    with pytest.raises(ValueError, match="batch_size"):
        run_batch(scenario, 0)
    with pytest.raises(ValueError, match="physics_substeps"):
        run_batch(scenario, 1, physics_substeps=0)
    with pytest.raises(ValueError, match="leading axis"):
        run_batch(scenario, 3, FuzzyRuleBase.stack([FuzzyRuleBase.table2()] * 2))


@pytest.mark.parametrize("shared_noise", [False, True])
def test_runs_split_over_threads_change_nothing(shared_noise: bool) -> None:
    scenario = _bursty_lemniscate()  # burst states on every link, one per run or shared
    one = run_batch(
        scenario, 17, duration_s=1.5, record_trace=True, shared_noise=shared_noise, threads=1
    )
    two = run_batch(
        scenario, 17, duration_s=1.5, record_trace=True, shared_noise=shared_noise, threads=2
    )
    _assert_same_run(two, one, atol=0.0)
    assert two.summaries == one.summaries
    assert run_batch(scenario, 17, duration_s=0.1, threads=2).metrics is not None


def test_thread_counts_follow_the_batch() -> None:
    assert batch_module._thread_count(None, 1) == 1
    assert batch_module._thread_count(2, 15) == 1  # under 8 runs a thread
    assert batch_module._thread_count(2, 16) == 2
    assert batch_module._thread_count(1, 1000) == 1
    with pytest.raises(ValueError, match="threads"):
        run_batch(load_scenario(SCENARIOS / "paper.yaml"), 2, duration_s=0.1, threads=0)

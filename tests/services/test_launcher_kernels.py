"""Which way each process of `swarm up` runs the control kernels (SWARM_KERNELS) and the
register model (SWARM_NATIVE)."""

from __future__ import annotations

from pathlib import Path

import pytest

from robot_firmware.control.kernels import KERNELS_ENV
from robot_firmware.native import NATIVE_ENV
from services.launcher.launcher import Launcher, LaunchPlan
from tests.support.stand_in_processes import StandInFactory, StandInProcess

PAPER = Path(__file__).resolve().parents[2] / "configs" / "scenarios" / "paper.yaml"


class EnvRecordingFactory(StandInFactory):
    def __init__(self) -> None:
        super().__init__()
        self.envs: list[dict[str, str]] = []

    def __call__(self, argv: list[str], log: object, env: dict[str, str]) -> StandInProcess:
        self.envs.append(env)
        return super().__call__(argv, log, env)


def test_robots_run_the_ahead_of_time_kernels_and_the_world_the_jit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(KERNELS_ENV, raising=False)
    monkeypatch.delenv(NATIVE_ENV, raising=False)
    plan = LaunchPlan(
        scenario=PAPER, robots=("robot1", "robot2"), out_dir=tmp_path, dashboard=False
    )
    factory = EnvRecordingFactory()
    launcher = Launcher(plan, factory=factory)  # type: ignore[arg-type]
    names = list(launcher.children)
    try:
        for name in names:
            launcher.start(name)
        modes = {name: env.get(KERNELS_ENV) for name, env in zip(names, factory.envs, strict=True)}
        native = {name: env.get(NATIVE_ENV) for name, env in zip(names, factory.envs, strict=True)}
    finally:
        launcher.shutdown(grace_s=0.0)
    assert modes.pop("robot1") == "aot" and modes.pop("robot2") == "aot"
    assert modes and set(modes.values()) == {"jit"}
    assert native.pop("robot1") == "mypyc" and native.pop("robot2") == "mypyc"
    assert native and set(native.values()) == {None}

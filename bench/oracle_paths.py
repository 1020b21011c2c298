"""Run the firmware and the world step on the numpy oracle instead of the compiled kernels.

tests/control/oracle.py states the control step and the body step in numpy (the form the
project ran before its kernels were compiled); the benchmarks time both paths in the same run,
so that their ratio holds even on a loaded machine.  The batch simulator's numpy path is
tests/world/oracle.py's `run_batch_oracle` (bench/batch_throughput.py).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import dataclasses  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import ArrayLike  # noqa: E402

import robot_firmware.firmware as firmware_module  # noqa: E402
import world.step as step_module  # noqa: E402
from robot_firmware.control.controller import (  # noqa: E402
    ControllerParams,
    ControllerState,
    ControlOutputs,
    OneRobotControl,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase  # noqa: E402
from tests.control import oracle  # noqa: E402

PATHS = ("compiled", "oracle")


class OracleOneRobotControl(OneRobotControl):
    """`OneRobotControl`'s input and role arrays, stepped by the numpy oracle."""

    def __init__(self, params: ControllerParams, peers: int, rule_base: FuzzyRuleBase) -> None:
        self._beams = len(params.sonar_beam_angles_rad)
        super().__init__(params, peers, rule_base)

    @property
    def state(self) -> ControllerState:
        return self._state

    def set_rule_base(self, rule_base: FuzzyRuleBase) -> None:
        super().set_rule_base(rule_base)
        self._rule_base = rule_base

    def reset(self, previous_counts: ArrayLike) -> None:
        fresh = ControllerState.initial((), self._beams)
        counts = np.array(previous_counts, dtype=np.int64)
        self._state = dataclasses.replace(
            fresh, estimator=dataclasses.replace(fresh.estimator, previous_counts=counts)
        )

    def load(self, state: ControllerState) -> None:
        self._state = state

    def step(self, t_s: float, sonar_fresh: bool) -> ControlOutputs:
        copied = {
            f.name: np.array(getattr(self.inputs, f.name))
            for f in dataclasses.fields(self.inputs)
            if f.name not in ("t_s", "sonar_fresh")
        }
        inputs = dataclasses.replace(self.inputs, t_s=t_s, sonar_fresh=sonar_fresh, **copied)
        role = dataclasses.replace(
            self.role,
            **{f.name: np.array(getattr(self.role, f.name)) for f in dataclasses.fields(self.role)},
        )
        self._state, outputs = oracle.control_step(
            self._state, inputs, role, self._rule_base, self.params
        )
        return outputs


@contextlib.contextmanager
def control_path(path: str) -> Iterator[None]:
    """Within the block, `path` ('compiled' or 'oracle') steers and moves the bodies."""
    if path not in PATHS:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    saved = (
        firmware_module.OneRobotControl,
        step_module.step_bodies,
        step_module.resolve_contacts,
    )
    if path == "oracle":
        firmware_module.OneRobotControl = OracleOneRobotControl  # type: ignore[misc]
        step_module.step_bodies = oracle.step_bodies  # type: ignore[assignment]
        step_module.resolve_contacts = oracle.resolve_contacts  # type: ignore[assignment]
    try:
        yield
    finally:
        (
            firmware_module.OneRobotControl,  # type: ignore[misc]
            step_module.step_bodies,
            step_module.resolve_contacts,
        ) = saved

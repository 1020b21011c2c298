"""`OneRobotControl`, the firmware's way into the control kernel, is `control_step` bit for bit:
the same tick on arrays made once, its state in two sets used in turn."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    OneRobotControl,
    RobotRole,
    control_step,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase

PEERS = 3


def _same(got: object, want: object, path: str = "") -> None:
    if hasattr(want, "__dataclass_fields__"):
        for f in fields(want):  # type: ignore[arg-type]
            _same(getattr(got, f.name), getattr(want, f.name), f"{path}.{f.name}")
        return
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want), err_msg=path)


def _inputs(rng: np.random.Generator, t_s: float, beams: int) -> ControlInputs:
    sonar = rng.uniform(0.05, 1.0, beams)
    sonar[rng.random(beams) < 0.5] = np.inf
    return ControlInputs(
        t_s=t_s,
        encoder_counts=rng.integers(-3000, 3000, 4),
        fix_pose=rng.normal(0.0, 0.3, 3),
        fix_valid=np.array(rng.random() < 0.4),
        sonar_range_m=sonar,
        sonar_fresh=bool(rng.random() < 0.3),
        peer_pose=rng.normal(0.0, 0.6, (PEERS, 3)),
        peer_rate=rng.normal(0.0, 0.4, (PEERS, 3)),
        peer_stamp_s=t_s - rng.uniform(-0.05, 1.2, PEERS),
        peer_valid=np.array([False, True, True]),
        peer_is_leader=np.array([False, True, False]),
        reference_pose=rng.normal(0.0, 1.0, 3),
        reference_rate=rng.normal(0.0, 0.3, 3),
        peer_stopped=rng.random(PEERS) < 0.5,
    )


def test_one_robot_control_is_control_step_bit_for_bit() -> None:
    params = ControllerParams()
    beams = len(params.sonar_beam_angles_rad)
    rules = FuzzyRuleBase.table2()
    rng = np.random.default_rng(21)
    control = OneRobotControl(params, PEERS, rules)
    state = ControllerState.initial((), beams)
    for tick in range(60):
        t_s = 1.0 + 0.01 * tick
        inputs = _inputs(rng, t_s, beams)
        role = RobotRole(
            is_leader=np.array(tick % 20 < 5),
            slot_distance_m=np.array(1.2),
            slot_angle_rad=np.array(2.6),
        )
        if tick == 30:  # a fresh start, as after a gap: encoders counted from here
            control.reset(inputs.encoder_counts)
            state = ControllerState.initial((), beams)
            state = replace(
                state,
                estimator=replace(state.estimator, previous_counts=inputs.encoder_counts.copy()),
            )
        if tick == 45:  # a state from elsewhere (moved 5 cm, offset nudged), loaded
            est = state.estimator
            state = replace(
                state,
                estimator=replace(est, pose=est.pose + [0.05, 0.0, 0.0]),
                avoidance_offset_m=state.avoidance_offset_m + 0.01,
            )
            control.load(state)
        for name in (
            "encoder_counts", "fix_pose", "fix_valid", "sonar_range_m", "peer_pose", "peer_rate",
            "peer_stamp_s", "peer_valid", "peer_is_leader", "reference_pose", "reference_rate",
            "peer_stopped",
        ):  # fmt: skip
            getattr(control.inputs, name)[...] = getattr(inputs, name)
        control.role.is_leader[...] = role.is_leader
        control.role.slot_distance_m[...] = role.slot_distance_m
        control.role.slot_angle_rad[...] = role.slot_angle_rad
        got = control.step(t_s, inputs.sonar_fresh)
        state, want = control_step(state, inputs, role, rules, params)
        _same(got, want, f"outputs at tick {tick}")
        _same(control.state, state, f"state at tick {tick}")
    assert np.any(want.active)  # the cases drove the robot, not only held it

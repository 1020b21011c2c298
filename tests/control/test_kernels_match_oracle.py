"""The compiled kernels equal the numpy statement of the same math (tests/control/oracle.py).

Seeded random batches of robots, with the edge cases mixed in: headings past ±π, errors that
saturate the wheels and the integral, robots with no peers and no echoes, stale and invalid
peers, stopped peers with a side to go round them already chosen or not, sonar sweeps fresh and
held, bodies near enough for the approach guard to cut the command, unlocalised robots, fuzzy
inputs exactly on the set centres and beyond the outer ones, and bodies in contact. Agreement
is required to 1e-12, relative for magnitudes above 1 (gains of 60 multiply last-bit
differences between numpy's and the compiled arithmetic into the 12th digit).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    RobotRole,
    control_step,
)
from robot_firmware.control.estimation import EstimatorState
from robot_firmware.control.fuzzy import FuzzyRuleBase, infer
from robot_firmware.control.pid import PidState
from swarm_config.body import BodyParams
from tests.control import oracle
from world.physics import BodyState, resolve_contacts, step_bodies

TOLERANCE = 1e-12
BATCH = (8, 5)  # runs x robots
PEERS = 5


def _random_rule_base(rng: np.random.Generator) -> FuzzyRuleBase:
    bases = []
    for _ in range(BATCH[0]):
        n_e, n_d = rng.integers(2, 8, size=2)
        ce = np.sort(rng.uniform(-1, 1, n_e)) + np.arange(n_e) * 1e-3
        cd = np.sort(rng.uniform(-1, 1, n_d)) + np.arange(n_d) * 1e-3
        bases.append(FuzzyRuleBase.from_centres(ce, cd, rng.uniform(-1, 1, (n_e, n_d))))
    return FuzzyRuleBase.stack(bases).expand_dims((1,))


def _random_case(
    rng: np.random.Generator, sonar_count: int
) -> tuple[ControllerState, ControlInputs, RobotRole]:
    b = BATCH
    s = sonar_count
    pose = rng.normal(0.0, 1.0, b + (3,))
    pose[..., 2] = rng.uniform(-12.0, 12.0, b)  # headings far past ±π
    state = ControllerState(
        estimator=EstimatorState(
            pose=pose,
            rate=rng.normal(0.0, 0.3, b + (3,)),
            previous_counts=rng.integers(-5000, 5000, b + (4,)),
            localised=rng.random(b) < 0.8,
        ),
        pid=PidState(
            integral=rng.uniform(-0.15, 0.15, b + (3,)),
            previous_error=rng.normal(0.0, 0.2, b + (3,)),
            error_rate=rng.normal(0.0, 0.5, b + (3,)),
            saturated=rng.random(b) < 0.3,
            started=rng.random(b) < 0.8,
        ),
        avoidance_offset_m=rng.normal(0.0, 0.05, b + (2,)),
        echo_points_m=pose[..., None, :2] + rng.normal(0.0, 0.5, b + (s, 2)),
        echo_valid=rng.random(b + (s,)) < 0.5,
        circulation_side=rng.choice([-1.0, 0.0, 1.0], b + (PEERS,)),
    )
    near = pose[..., None, :] + rng.normal(0.0, 0.5, b + (PEERS, 3))  # peers close by
    sonar = rng.uniform(0.0, 1.0, b + (s,))
    sonar[rng.random(b + (s,)) < 0.4] = np.inf  # no echo
    sonar[1] = np.inf  # runs with no echoes at all
    peer_valid = rng.random(b + (PEERS,)) < 0.7
    peer_valid[2] = False  # runs whose robots hear no peer
    leader = np.zeros(b, dtype=bool)
    leader[:, 0] = True
    inputs = ControlInputs(
        t_s=3.0,
        encoder_counts=state.estimator.previous_counts + rng.integers(-400, 400, b + (4,)),
        fix_pose=pose + rng.normal(0.0, 0.05, b + (3,)) + [0.0, 0.0, 6.2],
        fix_valid=rng.random(b) < 0.5,
        sonar_range_m=sonar,
        sonar_fresh=True,
        peer_pose=near,
        peer_rate=rng.normal(0.0, 0.5, b + (PEERS, 3)),
        peer_stamp_s=3.0 - rng.uniform(-0.1, 1.5, b + (PEERS,)),  # some stale, some ahead
        peer_valid=peer_valid,
        peer_is_leader=np.broadcast_to(np.arange(PEERS) == 0, b + (PEERS,)),
        reference_pose=np.array([1.0, -0.5, 3.1]),
        reference_rate=np.array([0.2, 0.1, 0.3]),
        peer_stopped=rng.random(b + (PEERS,)) < 0.5,
    )
    role = RobotRole(
        is_leader=leader,
        slot_distance_m=rng.uniform(0.5, 1.5, b),
        slot_angle_rad=rng.uniform(-np.pi, np.pi, b),
    )
    return state, inputs, role


def _assert_same(kernel: object, spec: object, path: str = "") -> None:
    if hasattr(spec, "__dataclass_fields__"):
        for f in fields(spec):  # type: ignore[arg-type]
            _assert_same(getattr(kernel, f.name), getattr(spec, f.name), f"{path}.{f.name}")
        return
    got = np.asarray(kernel)
    want = np.asarray(spec)
    assert got.shape == want.shape, path
    if want.dtype == bool or np.issubdtype(want.dtype, np.integer):
        np.testing.assert_array_equal(got, want, err_msg=path)
    else:
        np.testing.assert_allclose(got, want, rtol=TOLERANCE, atol=TOLERANCE, err_msg=path)


PARAMS = {
    "default": ControllerParams(),
    "saturating": ControllerParams(kp=(60.0, 60.0, 60.0), max_wheel_speed_radps=2.0),
    "fixed gains": ControllerParams(fuzzy_enabled=False),
}


@pytest.mark.parametrize("name", list(PARAMS))
@pytest.mark.parametrize("sonar_fresh", [True, False])
def test_control_step_equals_the_oracle(name: str, sonar_fresh: bool) -> None:
    params = PARAMS[name]
    rng = np.random.default_rng(11)
    rules = _random_rule_base(rng)
    state, inputs, role = _random_case(rng, len(params.sonar_beam_angles_rad))
    inputs = ControlInputs(**{**inputs.__dict__, "sonar_fresh": sonar_fresh})
    for _ in range(4):  # a few ticks, so the state carried between them is compared too
        got_state, got_out = control_step(state, inputs, role, rules, params)
        want_state, want_out = oracle.control_step(state, inputs, role, rules, params)
        _assert_same(got_state, want_state, "state")
        _assert_same(got_out, want_out, "outputs")
        state = want_state
        inputs = ControlInputs(**{**inputs.__dict__, "t_s": inputs.t_s + params.control_period_s})
    if name == "saturating":
        assert np.any(want_state.pid.saturated)
    # Bodies are close enough in these cases for the approach guard to change commands.
    unguarded = params.model_copy(update={"approach_guard": False})
    _, free_out = oracle.control_step(state, inputs, role, rules, unguarded)
    assert np.any(np.abs(free_out.wheel_speed_radps - want_out.wheel_speed_radps) > 1e-6)


def test_one_robot_equals_its_row_of_a_batch() -> None:
    params = ControllerParams()
    rng = np.random.default_rng(12)
    rules = _random_rule_base(rng)
    state, inputs, role = _random_case(rng, len(params.sonar_beam_angles_rad))
    _, batch_out = control_step(state, inputs, role, rules, params)

    def row(x: object) -> object:
        a = np.asarray(x)
        return a[3, 2] if a.ndim >= 2 and a.shape[:2] == BATCH else a

    def pick(obj: object) -> object:
        kw = {f.name: getattr(obj, f.name) for f in fields(obj)}  # type: ignore[arg-type]
        return type(obj)(
            **{k: pick(v) if hasattr(v, "__dataclass_fields__") else row(v) for k, v in kw.items()}
        )

    rules_one = FuzzyRuleBase(
        error_centres=rules.error_centres[3, 0],
        rate_centres=rules.rate_centres[3, 0],
        error_set_count=rules.error_set_count[3, 0],
        rate_set_count=rules.rate_set_count[3, 0],
        rule_outputs=rules.rule_outputs[3, 0],
    )
    one_inputs = pick(inputs)
    _, one_out = control_step(pick(state), one_inputs, pick(role), rules_one, params)  # type: ignore[arg-type]
    _assert_same(one_out, pick(batch_out))


def test_fuzzy_kernel_equals_the_oracle_on_and_between_the_set_edges() -> None:
    rng = np.random.default_rng(13)
    for _ in range(30):
        n_e, n_d = rng.integers(2, 8, size=2)
        ce = np.sort(rng.uniform(-1, 1, n_e)) + np.arange(n_e) * 1e-3
        cd = np.sort(rng.uniform(-1, 1, n_d)) + np.arange(n_d) * 1e-3
        rules = rng.uniform(-1, 1, size=(n_e, n_d))
        base = FuzzyRuleBase.from_centres(ce, cd, rules)
        # every centre exactly, just either side of it, beyond the outer sets, and random
        edges_e = np.concatenate([ce, np.nextafter(ce, -9), np.nextafter(ce, 9), [-5.0, 5.0]])
        edges_d = np.concatenate([cd, np.nextafter(cd, -9), np.nextafter(cd, 9), [-5.0, 5.0]])
        e = np.concatenate([np.repeat(edges_e, edges_d.size), rng.uniform(-1.5, 1.5, 200)])
        d = np.concatenate([np.tile(edges_d, edges_e.size), rng.uniform(-1.5, 1.5, 200)])
        got = infer(base, e, d)
        np.testing.assert_allclose(got, oracle.infer(base, e, d), rtol=0.0, atol=TOLERANCE)
        np.testing.assert_allclose(
            got, oracle.infer_full_product(ce, cd, rules, e, d), rtol=0.0, atol=TOLERANCE
        )


@pytest.mark.parametrize("dt_s", [0.001, 0.01, 0.05])
def test_body_step_equals_the_oracle(dt_s: float) -> None:
    rng = np.random.default_rng(14)
    params = BodyParams()
    shape = (7, 4)
    pose = rng.normal(0.0, 1.0, shape + (3,))
    pose[..., 2] = rng.uniform(-np.pi, np.pi, shape) * 0.999 + np.pi * (rng.random(shape) < 0.3)
    state = BodyState(
        pose=pose,
        wheel_speed_radps=rng.normal(0.0, 10.0, shape + (4,)),
        wheel_angle_rad=rng.normal(0.0, 100.0, shape + (4,)),
        slip=rng.normal(0.0, 0.05, shape + (4,)),
    )
    duty = rng.uniform(-1.5, 1.5, shape + (4,))  # saturates beyond ±1
    noise = rng.standard_normal((1,) + shape[1:] + (4,))  # shared noise broadcasts
    _assert_same(
        step_bodies(state, duty, dt_s, noise, params),
        oracle.step_bodies(state, duty, dt_s, noise, params),
    )


def test_contacts_equal_the_oracle() -> None:
    rng = np.random.default_rng(15)
    positions = rng.uniform(-1.0, 1.0, (20, 6, 2))
    positions[0, 1] = positions[0, 0]  # coincident centres
    obstacles = rng.uniform(-1.0, 1.0, (4, 2))
    radii = rng.uniform(0.05, 0.3, 4)
    got, got_report = resolve_contacts(positions, 0.3, obstacles, radii)
    want, want_report = oracle.resolve_contacts(positions, 0.3, obstacles, radii)
    _assert_same(got, want)
    _assert_same(got_report, want_report)
    assert want_report.robot_robot.any() and want_report.robot_obstacle.any()
    no_obstacles, _ = resolve_contacts(positions, 0.3, np.zeros((0, 2)), np.zeros(0))
    _assert_same(
        no_obstacles, oracle.resolve_contacts(positions, 0.3, np.zeros((0, 2)), np.zeros(0))[0]
    )

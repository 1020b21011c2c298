"""The control kernels compiled ahead of time (robot_firmware/control/aot.py, kernels.py).

A robot process (SWARM_KERNELS=aot) runs the same control tick as numba's JIT without
importing numba; a module built from other sources is never loaded; a call with types the
module was not built for runs the Python function instead of the compiled one.
"""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from robot_firmware.control import kernels
from robot_firmware.control.controller import (
    ControlInputs,
    ControllerParams,
    ControllerState,
    RobotRole,
    control_step,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase
from tests.support.python_child import run_python

TOLERANCE = 1e-12


@pytest.fixture(scope="module")
def aot_built() -> Path:
    """The module for the current sources (built now, in the default place, if missing)."""
    module_path, _ = kernels.module_paths(kernels.source_hash())
    if not module_path.is_file():
        built = run_python(
            "from robot_firmware.control.aot import main; main()", {"SWARM_KERNELS": "jit"}
        )
        assert built.returncode == 0, built.stderr.decode()
    assert module_path.is_file()
    return module_path


def _cases(count: int) -> list[tuple[ControllerState, ControlInputs, RobotRole, FuzzyRuleBase]]:
    rng = np.random.default_rng(13)
    params = ControllerParams()
    sonar = len(params.sonar_beam_angles_rad)
    robots = 4
    cases = []
    state = ControllerState.initial((), sonar)
    for i in range(count):
        gaps = rng.uniform(0.0, 0.6, sonar)
        gaps[rng.random(sonar) < 0.5] = np.inf
        inputs = ControlInputs(
            t_s=1.0 + 0.01 * i,
            encoder_counts=rng.integers(-3000, 3000, 4),
            fix_pose=rng.normal(0.0, 1.0, 3),
            fix_valid=np.array(i % 3 == 0),
            sonar_range_m=gaps,
            sonar_fresh=i % 5 == 0,
            peer_pose=rng.normal(0.0, 0.8, (robots, 3)),
            peer_rate=rng.normal(0.0, 0.3, (robots, 3)),
            peer_stamp_s=1.0 + 0.01 * i - rng.uniform(0.0, 1.5, robots),
            peer_valid=rng.random(robots) < 0.8,
            peer_is_leader=np.arange(robots) == 0,
            reference_pose=rng.normal(0.0, 1.0, 3),
            reference_rate=rng.normal(0.0, 0.5, 3),
            peer_stopped=rng.random(robots) < 0.3,
        )
        role = RobotRole(np.array(i % 2 == 0), np.array(1.2), np.array(2.5))
        cases.append((state, inputs, role, FuzzyRuleBase.table2()))
        state, _ = control_step(state, inputs, role, FuzzyRuleBase.table2(), params)
    return cases


AOT_STEPS = """
import pickle, sys
from robot_firmware.control import kernels
from robot_firmware.control.controller import ControllerParams, control_step, _control_rows_serial
cases = pickle.loads(sys.stdin.buffer.read())
results = [control_step(*case, ControllerParams()) for case in cases]
sys.stdout.buffer.write(pickle.dumps({
    "mode": kernels.MODE, "numba": "numba" in sys.modules, "llvmlite": "llvmlite" in sys.modules,
    "mismatches": getattr(_control_rows_serial, "mismatches", None), "results": results,
}))
"""


def test_robot_process_runs_the_jit_tick_without_numba(aot_built: Path) -> None:
    cases = _cases(40)
    ran = run_python(AOT_STEPS, {"SWARM_KERNELS": "aot"}, pickle.dumps(cases))
    assert ran.returncode == 0, ran.stderr.decode()
    got = pickle.loads(ran.stdout)
    assert got["mode"] == "aot"
    assert not got["numba"] and not got["llvmlite"]
    assert got["mismatches"] == 0  # every tick took the compiled function
    params = ControllerParams()
    for case, (aot_state, aot_out) in zip(cases, got["results"], strict=True):
        jit_state, jit_out = control_step(*case, params)
        for name in vars(jit_out):
            np.testing.assert_allclose(
                getattr(aot_out, name), getattr(jit_out, name), rtol=TOLERANCE, atol=TOLERANCE
            )
        np.testing.assert_allclose(
            aot_state.estimator.pose, jit_state.estimator.pose, atol=TOLERANCE
        )
        np.testing.assert_allclose(aot_state.pid.integral, jit_state.pid.integral, atol=TOLERANCE)


def test_edited_kernel_source_changes_the_hash(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    copy = tmp_path / "control"
    shutil.copytree(kernels.PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(kernels, "PACKAGE_DIR", copy)
    before = kernels.source_hash()
    pid = copy / "pid.py"
    pid.write_text(pid.read_text() + "\n# an edit\n")
    assert kernels.source_hash() != before


def test_module_of_other_sources_is_not_loaded(aot_built: Path, tmp_path: Path) -> None:
    """A module built for another hash (an old build) is never taken: the JIT runs."""
    other_hash = "0" * 20
    module_path, exports_path = kernels.module_paths(other_hash, tmp_path)
    shutil.copy(aot_built, module_path)
    exports_path.write_text(json.dumps({"source_hash": other_hash, "functions": {}}))
    code = "import sys; from robot_firmware.control import kernels; print(kernels.MODE)"
    ran = run_python(code, {"SWARM_KERNELS": "aot", kernels.AOT_DIR_ENV: str(tmp_path)})
    assert ran.returncode == 0, ran.stderr.decode()
    assert ran.stdout.decode().split() == ["jit"]
    note = ran.stderr.decode().strip().splitlines()
    assert len(note) == 1 and "using numba's JIT" in note[0]


def test_unknown_kernel_mode_is_named_and_the_jit_runs() -> None:
    code = "from robot_firmware.control import kernels; print(kernels.MODE)"
    ran = run_python(code, {"SWARM_KERNELS": "fast"})
    assert ran.returncode == 0
    assert ran.stdout.decode().split() == ["jit"]
    assert "SWARM_KERNELS='fast' is not one of" in ran.stderr.decode()


JIT_COMMAND = """
import os
from services.cli.main import main
code = main({argv!r})
from robot_firmware.control import kernels
print(code, kernels.MODE, os.environ["SWARM_KERNELS"])
"""


@pytest.mark.slow
@pytest.mark.parametrize("command", ["sim", "tune"])
def test_sim_and_tune_run_the_jit_under_swarm_kernels_aot(
    aot_built: Path, tmp_path: Path, command: str
) -> None:
    """SWARM_KERNELS=aot is a robot process's setting: the batch simulator's kernels call the
    control kernels, which must be numba's.  Before, sim and tune took the ahead-of-time
    module's functions and numba failed to compile the simulator's tick ("Cannot determine
    Numba type of AotKernel") whenever its cache was cold, after making the output folder."""
    out = str(tmp_path / "run")
    paper = "configs/scenarios/paper.yaml"
    argv = {
        "sim": ["sim", "--scenario", paper, "--out", out, "--duration", "0.5", "--no-figures"],
        "tune": ["tune", "--scenario", paper, "--out", out, "--budget", "2", "--duration", "0.1"],
    }[command]
    ran = run_python(JIT_COMMAND.format(argv=argv), {"SWARM_KERNELS": "aot"})
    assert ran.returncode == 0, ran.stderr.decode()
    # The command ran on the JIT; the variable is left as it was for the caller.
    assert ran.stdout.decode().splitlines()[-1].split() == ["0", "jit", "aot"]


def test_sim_in_a_process_already_on_the_aot_module_is_refused_in_one_line(
    aot_built: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    code = (
        "from robot_firmware.control import kernels\n"
        "from services.cli.main import main\n"
        f"print(main(['sim', '--out', {str(out)!r}, '--duration', '0.5']))\n"
    )
    ran = run_python(code, {"SWARM_KERNELS": "aot"})
    assert ran.returncode == 0, ran.stderr.decode()
    assert ran.stdout.decode().split() == ["2"]
    assert ran.stderr.decode().splitlines() == [
        "swarm sim: this process already runs the control kernels aot ($SWARM_KERNELS); swarm "
        "sim needs numba's JIT: run it with SWARM_KERNELS unset or jit"
    ]
    assert not out.exists()


def test_call_with_other_types_runs_the_python_function() -> None:
    compiled_calls: list[object] = []

    def compiled(a: object, t: object, x: object) -> str:
        compiled_calls.append(a)
        return "compiled"

    def python(a: object, t: object, x: object) -> str:
        return "python"

    spec = [["a", "<f8", 2], ["t", [["b"], ["i"]]], ["f"]]
    kernel = kernels.AotKernel(compiled, spec, python)
    good = np.zeros((2, 3))
    assert kernel(good, (True, 3), 1.5) == "compiled"
    for bad in (
        (good.astype(np.float32), (True, 3), 1.5),  # dtype
        (np.zeros(3), (True, 3), 1.5),  # dimensions
        (np.zeros((3, 2)).T, (True, 3), 1.5),  # not C-contiguous
        (good, (True,), 1.5),  # tuple length
        (good, (True, 3.0), 1.5),  # float for an int
        (good, (True, 3), "1.5"),
    ):
        assert kernel(*bad) == "python"
    assert kernel.mismatches == 6
    assert len(compiled_calls) == 1


def test_arguments_seen_checked_are_trusted_but_their_scalars_are_checked_every_call() -> None:
    calls: list[str] = []

    def compiled(a: object, t: object, x: object) -> str:
        calls.append("compiled")
        return "compiled"

    spec = [["a", "<f8", 1], ["t", [["a", "<i8", 1]]], ["f"]]
    kernel = kernels.AotKernel(compiled, spec, lambda a, t, x: "python")
    array, pair = np.zeros(3), (np.zeros(2, dtype=np.int64),)
    for step in range(3):
        assert kernel(array, pair, 0.1 * step) == "compiled"
    assert kernel(array, pair, None) == "python"  # a trusted set, a scalar of another type
    for _ in range(10):  # new tuples each call: checked in full, and only a few kept
        assert kernel(array, (np.zeros(2, dtype=np.int64),), 1.0) == "compiled"
    assert len(kernel._trusted) <= kernels.AotKernel.TRUSTED_CALLS
    assert kernel(array, (np.zeros(2),), 1.0) == "python"  # a float array where ints go


ROBOT_IMPORTS = """
import sys
import services.cli.main
services.cli.main.build_parser("robot")
import robot_firmware.runtime
from robot_firmware.control import kernels
heavy = sorted({m.split(".")[0] for m in sys.modules} & {"numba", "llvmlite", "scipy", "world"})
print(kernels.MODE, ",".join(heavy) or "-")
"""


def test_swarm_robot_loads_neither_numba_nor_the_world(aot_built: Path) -> None:
    ran = run_python(ROBOT_IMPORTS, {"SWARM_KERNELS": "aot"})
    assert ran.returncode == 0, ran.stderr.decode()
    assert ran.stdout.decode().split() == ["aot", "-"]

"""Build the control kernels ahead of time (numba.pycc) for robot processes (kernels.py).

The build runs the kernels once through numba's JIT on one robot, as the firmware calls them
(`OneRobotControl.step`, `sonar_beam_points`; `control_step` too), so numba infers the same
argument types; every kernel with exactly one signature so inferred (and not the parallel batch
form) is then exported, under that signature, from one extension module named after
`kernels.source_hash()`. A JSON file beside it lists each export's symbol and the argument
types (`AotKernel` checks them on every call). Modules of other hashes in the directory are
removed.

    .venv/bin/python -m robot_firmware.control.aot [--dir DIR] [--check]

--check only says whether the module for the current sources is there (exit 0) or not (1).
The build needs numba and a C compiler and takes about a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from robot_firmware.control import kernels


def _spec_of(numba_type: Any) -> kernels.ArgSpec | None:
    """The `AotKernel` check for a numba argument type; None if it cannot be exported."""
    from numba.core import types
    from numba.np.numpy_support import as_dtype

    if isinstance(numba_type, types.Array):
        if numba_type.layout != "C":
            return None
        return ["a", as_dtype(numba_type.dtype).str, numba_type.ndim]
    if isinstance(numba_type, types.BaseTuple):
        inner = [_spec_of(t) for t in numba_type.types]  # type: ignore[attr-defined]
        return None if any(s is None for s in inner) else ["t", inner]
    if isinstance(numba_type, types.Boolean):
        return ["b"]
    if isinstance(numba_type, types.Integer):
        return ["i"]
    if isinstance(numba_type, types.Float):
        return ["f"]
    return None


def _run_one_robot() -> None:
    """One robot's control tick and sonar points, with the firmware's argument types."""
    from robot_firmware.control.controller import (
        ControlInputs,
        ControllerParams,
        ControllerState,
        OneRobotControl,
        RobotRole,
        control_step,
        sonar_beam_points,
    )
    from robot_firmware.control.fuzzy import FuzzyRuleBase

    params = ControllerParams()
    sonar_count = len(params.sonar_beam_angles_rad)
    robots = 3
    state = ControllerState.initial((), sonar_count)
    for fresh in (True, False):
        inputs = ControlInputs(
            t_s=1.0,
            encoder_counts=np.zeros(4, dtype=np.int64),
            fix_pose=np.zeros(3),
            fix_valid=np.array(True),
            sonar_range_m=np.full(sonar_count, np.inf),
            sonar_fresh=fresh,
            peer_pose=np.zeros((robots, 3)),
            peer_rate=np.zeros((robots, 3)),
            peer_stamp_s=np.zeros(robots),
            peer_valid=np.ones(robots, dtype=bool),
            peer_is_leader=np.zeros(robots, dtype=bool),
            reference_pose=np.zeros(3),
            reference_rate=np.zeros(3),
            peer_stopped=np.zeros(robots, dtype=bool),
        )
        role = RobotRole(np.array(True), np.array(0.0), np.array(0.0))
        state, _ = control_step(state, inputs, role, FuzzyRuleBase.table2(), params)
        one = OneRobotControl(params, robots, FuzzyRuleBase.table2())
        one.step(1.0, fresh)  # the firmware's own way into control_robots
    sonar_beam_points(np.zeros(3), np.zeros(sonar_count), params)


def build(directory: Path | None = None) -> Path:
    """Compile the ahead-of-time module for the current sources into `directory`."""
    if kernels.MODE != "jit":
        raise RuntimeError(f"build with {kernels.KERNELS_ENV}=jit (this process runs aot)")
    _run_one_robot()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's pending deprecation
        from numba.pycc import CC

    directory = kernels.aot_dir() if directory is None else directory
    directory.mkdir(parents=True, exist_ok=True)
    hash_ = kernels.source_hash()
    name = kernels.module_name(hash_)
    functions: dict[str, dict[str, Any]] = {}
    compiler = CC(name)
    compiler.verbose = False
    with tempfile.TemporaryDirectory(dir=directory) as scratch:
        compiler.output_dir = scratch
        for index, (key, parallel, dispatcher) in enumerate(kernels.JIT_KERNELS):
            signatures = dispatcher.nopython_signatures
            if parallel or len(signatures) != 1 or key in functions:
                continue
            spec = [_spec_of(t) for t in signatures[0].args]
            if any(s is None for s in spec):
                continue
            symbol = f"k{index}_{dispatcher.py_func.__name__}"
            compiler.export(symbol, signatures[0])(dispatcher.py_func)
            functions[key] = {"symbol": symbol, "spec": spec}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            compiler.compile()
        module_path, exports_path = kernels.module_paths(hash_, directory)
        built = Path(scratch) / module_path.name
        os.replace(built, module_path)
    exports = {"source_hash": hash_, "functions": functions}
    exports_path.write_text(json.dumps(exports, indent=1) + "\n")
    for stale in directory.glob(kernels.MODULE_PREFIX + "*"):
        if name not in stale.name:
            if stale.is_dir():
                shutil.rmtree(stale, ignore_errors=True)
            else:
                stale.unlink(missing_ok=True)
    return module_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=None, help="where the module goes")
    parser.add_argument("--check", action="store_true", help="only say whether it is built")
    args = parser.parse_args(argv)
    hash_ = kernels.source_hash()
    if args.check:
        module_path, exports_path = kernels.module_paths(hash_, args.dir)
        there = module_path.is_file() and exports_path.is_file()
        print(f"{module_path}: {'built' if there else 'missing'}")
        return 0 if there else 1
    if args.dir is not None:
        os.environ[kernels.AOT_DIR_ENV] = str(args.dir)
    path = build(args.dir)
    exports = json.loads(kernels.module_paths(hash_, args.dir)[1].read_text())
    print(f"built {path} ({len(exports['functions'])} kernels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

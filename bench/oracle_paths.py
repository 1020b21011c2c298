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

import robot_firmware.firmware as firmware_module  # noqa: E402
import world.step as step_module  # noqa: E402
from tests.control import oracle  # noqa: E402

PATHS = ("compiled", "oracle")


@contextlib.contextmanager
def control_path(path: str) -> Iterator[None]:
    """Within the block, `path` ('compiled' or 'oracle') steers and moves the bodies."""
    if path not in PATHS:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    saved = (
        firmware_module.control_step,
        step_module.step_bodies,
        step_module.resolve_contacts,
    )
    if path == "oracle":
        firmware_module.control_step = oracle.control_step  # type: ignore[assignment]
        step_module.step_bodies = oracle.step_bodies  # type: ignore[assignment]
        step_module.resolve_contacts = oracle.resolve_contacts  # type: ignore[assignment]
    try:
        yield
    finally:
        (
            firmware_module.control_step,
            step_module.step_bodies,
            step_module.resolve_contacts,
        ) = saved

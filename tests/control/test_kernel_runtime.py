"""Kernels marked `allocates=False` (robot_firmware/control/kernels.py) are compiled without
numba's memory runtime: the batch simulator's control kernel (`control_robots`) takes its rows
as views, and with the runtime each view costs an atomic reference count."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from robot_firmware.control import kernels
from robot_firmware.control.controller import control_robots

pytestmark = [
    pytest.mark.skipif(kernels.MODE != "jit", reason="numba's JIT is not in use"),
    pytest.mark.skipif(
        getattr(kernels, "NO_RUNTIME_OPTION", None) is None,
        reason="this numba has no per-function memory runtime option",
    ),
]


@pytest.fixture
def kernels_declared_here() -> Iterator[None]:
    """Kernels a test declares are taken out of the ahead-of-time build's list again."""
    before = len(kernels.JIT_KERNELS)
    yield
    del kernels.JIT_KERNELS[before:]


def test_control_robots_is_compiled_without_the_memory_runtime() -> None:
    assert control_robots.targetoptions[kernels.NO_RUNTIME_OPTION] is False


def test_a_kernel_marked_as_not_allocating_does_not_compile_if_it_allocates(
    kernels_declared_here: None,
) -> None:
    @kernels.njit(allocates=False)
    def sum_of_a_copy(rows, i):  # type: ignore[no-untyped-def]
        return rows[i].copy().sum()

    @kernels.njit(allocates=False)
    def row_sum(rows, i):  # type: ignore[no-untyped-def]
        row = rows[i]
        total = 0.0
        for value in row:
            total += value
        return total

    rows = np.arange(6.0).reshape(2, 3)
    assert row_sum(rows, 1) == 12.0  # views alone need no runtime
    with pytest.raises(Exception, match="NRT required but not enabled"):
        sum_of_a_copy(rows, 1)

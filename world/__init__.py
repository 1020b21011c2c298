"""The world: physics of the robot bodies, sensor synthesis, radio medium, scenarios, metrics."""

# Before any kernel here is compiled: where numba caches them (robot_firmware/control/kernels.py
# `use_jit_cache`).
import robot_firmware.control.kernels  # noqa: F401

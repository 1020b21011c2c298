"""The robot's pins: a world sense message (DESIGN.md §3, wire/sense) applied to its fabric."""

from __future__ import annotations

from robot_firmware.fpga.fabric import Fabric
from robot_firmware.fpga.positioning import PositionFix
from robot_firmware.net.wire import SenseMessage


def apply_sense(fabric: Fabric, message: SenseMessage) -> None:
    """Drive the encoder, sonar and positioning pins from one sense message."""
    fix = message.fix
    fabric.hw_apply_sense(
        message.encoder_counts,
        message.sonar_echo_times_s,
        None
        if fix is None
        else PositionFix(fix.x_m, fix.y_m, fix.heading_rad, fix.stamp_ns, fix.valid),
    )

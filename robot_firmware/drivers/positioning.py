"""Positioning driver: global pose fixes from the indoor positioning receiver (DESIGN §4).

The receiver holds the last fix in X_UM, Y_UM (signed micrometres) and HEADING_URAD
(signed microradians in (-pi, pi]), counts fixes in SEQ and flags a usable fix with
STATUS.VALID. The pose is three registers, so a fix can land between two of the
reads; the driver reads them between two reads of SEQ and retries when SEQ moved:

    SEQ -> STATUS, X_UM, Y_UM, HEADING_URAD -> SEQ     (retry if the two SEQ differ)

at most MAX_READ_ATTEMPTS times per call. When SEQ still equals the sequence of the
fix last handed out, nothing new has come and the call costs that one read. A fix is
returned once: `read_fix` gives None until SEQ moves again. A new fix that is not VALID
(cut or stale by the time it is read) is consumed and gives None.

The driver does not read EVENTS (read-to-clear), so it takes nothing away from other
readers. A refused read is counted in `bus_errors` and the call gives None; the fix is
tried again at the next call.
"""

from __future__ import annotations

from dataclasses import dataclass

from robot_firmware.drivers.register_port import RegisterPort
from robot_firmware.fpga import positioning as positioning_map
from robot_firmware.fpga.address_map import POSITIONING_BASE
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.positioning import UM_PER_M, URAD_PER_RAD
from robot_firmware.fpga.registers import as_signed32

MAX_READ_ATTEMPTS = 3

_SEQ = POSITIONING_BASE + positioning_map.SEQ.offset
_STATUS = POSITIONING_BASE + positioning_map.STATUS.offset
_X_UM = POSITIONING_BASE + positioning_map.X_UM.offset
_Y_UM = POSITIONING_BASE + positioning_map.Y_UM.offset
_HEADING_URAD = POSITIONING_BASE + positioning_map.HEADING_URAD.offset
_VALID = positioning_map.STATUS_VALID.mask


@dataclass(frozen=True)
class PoseFix:
    """One consistent pose fix of the tracking system, in the world frame."""

    x_m: float
    y_m: float
    heading_rad: float
    """In (-pi, pi]."""
    sequence: int
    """SEQ of the receiver for this fix (32-bit, wraps)."""


class PositioningDriver:
    """Hands out each new valid fix of the positioning receiver once."""

    def __init__(self, bus: Bus) -> None:
        self._port = RegisterPort(bus)
        self._last_sequence: int | None = None
        self.torn_reads = 0
        """Pose reads that were repeated because a fix arrived during them."""

    @property
    def bus_errors(self) -> int:
        """Refused bus accesses of this driver since it was built."""
        return self._port.errors

    def read_fix(self) -> PoseFix | None:
        """The fix that arrived since the last call, if it is valid; None otherwise."""
        for _ in range(MAX_READ_ATTEMPTS):
            sequence = self._port.read(_SEQ)
            if sequence is None or sequence == self._last_sequence:
                return None
            status = self._port.read(_STATUS)
            x_um = self._port.read(_X_UM)
            y_um = self._port.read(_Y_UM)
            heading_urad = self._port.read(_HEADING_URAD)
            sequence_after = self._port.read(_SEQ)
            if status is None or x_um is None or y_um is None or heading_urad is None:
                return None
            if sequence_after is None:
                return None
            if sequence_after != sequence:
                self.torn_reads += 1
                continue
            self._last_sequence = sequence
            if not status & _VALID:
                return None
            return PoseFix(
                x_m=as_signed32(x_um) / UM_PER_M,
                y_m=as_signed32(y_um) / UM_PER_M,
                heading_rad=as_signed32(heading_urad) / URAD_PER_RAD,
                sequence=sequence,
            )
        return None

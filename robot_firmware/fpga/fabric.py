"""The FPGA fabric of one robot: every IP instance, wired together and mapped on the bus.

`Fabric` builds the peripherals, maps them at the addresses of `address_map`, feeds
the fabric clock of the PLL block to the IPs that count in it, routes the QEP speeds
and sonar widths through their digital filters, and connects the watchdog's cut to
every PWM generator. It is the one place where the world's pin-level signals enter
and leave the robot:

* `hw_apply_sense(encoder_counts, sonar_echo_times_s, fix)` applies one `wire/sense`
  message;
* `hw_read_actuation()` gives what the motor pins carry, for `wire/act`;
* `tick(dt_ns)` advances the time-driven behaviour of every IP;
* `faults` holds the register faults injected into the IPs (robot_firmware/fpga/faults.py).

The firmware side sees only `fabric.bus`.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

from robot_firmware.fpga.address_map import (
    CLOCK_BASE,
    DEFAULT_N_SONAR,
    MAX_SONAR,
    N_WHEELS,
    POSITIONING_BASE,
    PWM_BASES,
    QEP_BASES,
    SONAR_FILTER_BASE,
    SPEED_FILTER_BASE,
    SYSID_BASE,
    WATCHDOG_BASE,
    sonar_base,
)
from robot_firmware.fpga.bus import Bus
from robot_firmware.fpga.clock import ClockBlock
from robot_firmware.fpga.digital_filter import DigitalFilter
from robot_firmware.fpga.faults import RegisterFaults
from robot_firmware.fpga.positioning import PositionFix, PositioningReceiver
from robot_firmware.fpga.pwm import Pwm
from robot_firmware.fpga.qep import Qep
from robot_firmware.fpga.registers import Peripheral
from robot_firmware.fpga.sonar import Sonar
from robot_firmware.fpga.sysid import SystemId
from robot_firmware.fpga.watchdog import Watchdog


class FabricConfig(BaseModel):
    """Build-time options of the FPGA image."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    n_sonar: int = Field(default=DEFAULT_N_SONAR, ge=1, le=MAX_SONAR)


@dataclass(frozen=True)
class Actuation:
    """What the motor pins carry, per wheel."""

    duty: tuple[float, ...]
    """Signed duty cycle per wheel, -1..1; 0 for a disabled or cut output."""
    enabled: tuple[bool, ...]
    """Per wheel: enabled and not cut by the watchdog."""
    watchdog_expired: bool

    @property
    def any_enabled(self) -> bool:
        return any(self.enabled)


class Fabric:
    """All IP instances of one robot's FPGA, their wiring, and their bus."""

    def __init__(self, config: FabricConfig | None = None, bus: Bus | None = None) -> None:
        self.config = config if config is not None else FabricConfig()
        self.bus = bus if bus is not None else Bus()
        n_sonar = self.config.n_sonar
        self.now_ns = 0

        self.sysid = SystemId(n_sonar=n_sonar)
        self.clock = ClockBlock()
        self.watchdog = Watchdog()
        self.positioning = PositioningReceiver()
        self.sonar_filter = DigitalFilter("sonar_filter", channels=n_sonar)
        self.speed_filter = DigitalFilter("speed_filter", channels=N_WHEELS)
        clock_hz = self.clock.hw_fabric_clock_hz
        self.qep = tuple(
            Qep(f"qep{i}", clock_hz, _channel(self.speed_filter, i)) for i in range(N_WHEELS)
        )
        self.pwm = tuple(Pwm(f"pwm{i}", clock_hz) for i in range(N_WHEELS))
        self.sonar = tuple(
            Sonar(f"sonar{i}", clock_hz, _channel(self.sonar_filter, i)) for i in range(n_sonar)
        )
        for pwm in self.pwm:
            self.watchdog.hw_connect_cut(pwm.hw_set_safe_stop)

        placement: list[tuple[int, Peripheral]] = [
            (SYSID_BASE, self.sysid),
            (CLOCK_BASE, self.clock),
            (WATCHDOG_BASE, self.watchdog),
            (POSITIONING_BASE, self.positioning),
            *zip(QEP_BASES, self.qep, strict=True),
            *zip(PWM_BASES, self.pwm, strict=True),
            (SONAR_FILTER_BASE, self.sonar_filter),
            (SPEED_FILTER_BASE, self.speed_filter),
            *((sonar_base(i), sonar) for i, sonar in enumerate(self.sonar)),
        ]
        for base, peripheral in placement:
            self.bus.map(base, peripheral)
        # The clock first, so the other IPs count in the clock that holds after this step.
        self._tick_order: tuple[Peripheral, ...] = (
            self.clock,
            self.watchdog,
            self.positioning,
            *self.qep,
            *self.sonar,
        )
        self.faults = RegisterFaults(self)

    @property
    def peripherals(self) -> Iterator[Peripheral]:
        """Every IP instance, in address order."""
        return (peripheral for _, peripheral in self.bus.mapped())

    # -- time ------------------------------------------------------------------------

    def tick(self, dt_ns: int) -> None:
        """Advance every IP by `dt_ns` nanoseconds of fabric time."""
        if dt_ns < 0:
            raise ValueError(f"time runs forward: dt_ns={dt_ns}")
        self.now_ns += dt_ns
        for peripheral in self._tick_order:
            peripheral.tick(dt_ns)

    def advance(self, dt_ns: int, slice_ns: int) -> None:
        """Advance by `dt_ns` in fabric slices of `slice_ns` (the last one shorter if need be),
        with the state a `tick(slice_ns)` per slice leaves, bit for bit.

        The model's time resolution is the slice: an IP's events (a window latched, an echo
        timed, a countdown at zero) fall at the end of the slice in which they are due.  Whole
        slices in which no IP has an event are merged into one `tick`: there every IP's `tick`
        only adds the time up (each says how many slices it stays quiet, `quiet_slices`), and
        the slice of an event is ticked on its own, so an IP that reads another's state (the
        QEPs read the clock block's C0) reads it as it was at that slice.
        """
        if slice_ns <= 0:
            raise ValueError(f"a fabric slice lasts some time: slice_ns={slice_ns}")
        while dt_ns > 0:
            merged = dt_ns // slice_ns
            for peripheral in self._tick_order:
                quiet = peripheral.quiet_slices(slice_ns)
                if quiet is not None and quiet < merged:
                    merged = quiet
                    if merged == 0:
                        break
            step_ns = merged * slice_ns if merged else min(slice_ns, dt_ns)
            self.tick(step_ns)
            dt_ns -= step_ns

    # -- hardware side ---------------------------------------------------------------

    def hw_apply_sense(
        self,
        encoder_counts: Sequence[int],
        sonar_echo_times_s: Sequence[float | None],
        fix: PositionFix | None,
    ) -> None:
        """Apply one sense message: running 4x encoder counts per wheel, echo time per sonar
        (None = no echo), and a positioning fix (None = nothing new from the tracker).

        A message of the wrong shape raises ValueError and changes nothing.
        """
        if len(encoder_counts) != N_WHEELS:
            raise ValueError(f"{len(encoder_counts)} encoder counts for {N_WHEELS} wheels")
        try:
            counts_per_wheel = [operator.index(c) for c in encoder_counts]
        except TypeError:
            raise ValueError(f"encoder counts must be integers: {list(encoder_counts)!r}") from None
        if len(sonar_echo_times_s) != len(self.sonar):
            raise ValueError(f"{len(sonar_echo_times_s)} echo times for {len(self.sonar)} sonars")
        for qep, counts in zip(self.qep, counts_per_wheel, strict=True):
            qep.hw_set_encoder_counts(counts)
        for sonar, echo_time_s in zip(self.sonar, sonar_echo_times_s, strict=True):
            sonar.hw_set_echo_time(echo_time_s)
        if fix is not None:
            self.positioning.hw_set_fix(fix)

    def hw_read_actuation(self) -> Actuation:
        """Signed duty and enable of every PWM output, and the watchdog state."""
        outputs = [pwm.hw_output() for pwm in self.pwm]
        return Actuation(
            duty=tuple(out.duty for out in outputs),
            enabled=tuple(out.enabled for out in outputs),
            watchdog_expired=self.watchdog.hw_expired(),
        )


def _channel(digital_filter: DigitalFilter, channel: int) -> Callable[[int], int]:
    def push(sample: int) -> int:
        return digital_filter.hw_filter(channel, sample)

    return push

"""Register faults of one robot's FPGA: which are active, and how each IP model obeys them
(DESIGN.md §7, robustness semantics).

The faults are the register kind of `swarm_config.faults` (`REGISTER_FAULT_ADAPTER`). They act
below the firmware, on the hardware side of the IPs, so the firmware meets them only through
the registers it reads and the pins it drives, as it would on a board:

| fault               | IP hook                                   | lasts                  |
|---------------------|-------------------------------------------|------------------------|
| `encoder_stuck`     | `Qep.hw_cut_lines` of the wheel           | until cleared          |
| `encoder_bit_stuck` | `Qep.hw_force_count_bits` of the wheel    | until cleared          |
| `sonar_no_echo`     | `Sonar.hw_block_echo` of every ranger     | until cleared          |
| `pwm_stuck`         | `Pwm.hw_hold_output(duty)` of the wheel   | until cleared          |
| `pwm_saturated`     | `Pwm.hw_hold_output(+-1)` of the wheel    | until cleared          |
| `fix_cut`           | `PositioningReceiver.hw_block_fixes`      | until cleared          |
| `watchdog_expire`   | `Watchdog.hw_force_expire`                | until the next kick    |
| `tick_slow`         | none: the robot's runtime sleeps per tick | until cleared          |
| `clear_registers`   | every hook released                       |                        |

A fault on the same output as an active one replaces it (`pwm_stuck` and `pwm_saturated` share
a wheel's output; a second `tick_slow` sets a new delay), and `clear_registers` releases all.
The state of every IP is re-derived from the active set after each change, so clearing leaves
no trace but what the fault did while it lasted (edges lost while an encoder was cut, a fix
missed, an expiry counted in EXPIRE_COUNT). A restarted robot process builds a new fabric, so
its register faults are gone, as after a power cycle of the board.

A forced watchdog expiry lands at the end of the robot's next control tick (`land_pending`,
called after the firmware's watchdog kick and before the pins are published): the act message
of that tick shows the cut and the world drives the robot with the motors off for one control
period, until the firmware's next kick re-arms the watchdog (robot_firmware/fpga/watchdog.py).
Applied at once, the expiry would be undone by that same tick's kick before any act message
could show it. `tick_slow` has no IP: the runtime (robot_firmware/runtime.py) sleeps
`tick_extra_s` inside every control tick, before the act message leaves.

With no fault active the IPs run their normal path; each hook costs one attribute test there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from swarm_config.faults import (
    ClearRegistersFault,
    EncoderBitStuckFault,
    EncoderStuckFault,
    FixCutFault,
    PwmSaturatedFault,
    PwmStuckFault,
    RegisterFault,
    SonarNoEchoFault,
    TickSlowFault,
)

if TYPE_CHECKING:
    from robot_firmware.fpga.fabric import Fabric

MS_PER_S = 1000.0

_FaultKey = tuple[str | int, ...]


@dataclass(frozen=True)
class FaultEffect:
    """What one register fault does, for the register reference (docs/registers.md)."""

    fault: str
    acts_on: str
    """The register or pin the fault changes."""
    firmware_sees: str
    firmware_does: str


FAULT_EFFECTS: tuple[FaultEffect, ...] = (
    FaultEffect(
        "encoder_stuck",
        "`qepN` A/B inputs (`wheel`): no edge is decoded",
        "`COUNT` holds its value; `SPEED` and `SPEED_FILTERED` fall to 0 at the next window",
        "odometry takes the wheel as stopped; the pose drifts between fixes and each positioning "
        "fix pulls it back. Edges during the fault are lost, counting resumes when cleared",
    ),
    FaultEffect(
        "encoder_bit_stuck",
        "`qepN.COUNT` bit `bit` (`wheel`) reads `value`",
        "`COUNT` with that bit forced; the position behind it counts on",
        "the encoder driver unwraps the forced word, so a high bit that flips reads as a jump of "
        "2^bit counts; odometry moves by it and the next fixes pull the pose back",
    ),
    FaultEffect(
        "sonar_no_echo",
        "every `sonarN` receiver: no echo is heard",
        "each measurement triggered from then on ends after `TIMEOUT_TICKS` with "
        "`EVENTS.TIMEOUT`; `WIDTH_TICKS` keeps its last value",
        "the sonar driver sets every gap to infinity (nothing in range): APF sees no obstacle and "
        "no peer by sonar; peers' radio poses still repel",
    ),
    FaultEffect(
        "pwm_stuck",
        "`pwmN` output pins (`wheel`): signed `duty` whatever `CTRL`, `DUTY_TICKS` say",
        "register writes succeed as before; `STATUS.ACTIVE` and `STATUS.SATURATED` follow the "
        "held output",
        "its commands to that wheel have no effect and it does not know: the PID law drives the "
        "other three against the stuck wheel and the robot leaves its slot. The watchdog's cut "
        "still holds the pins low",
    ),
    FaultEffect(
        "pwm_saturated",
        "`pwmN` output pins (`wheel`): full duty in direction `sign`",
        "as `pwm_stuck` with duty +-1; `STATUS.SATURATED` is 1",
        "as `pwm_stuck`: the other wheels fight a wheel at full drive",
    ),
    FaultEffect(
        "fix_cut",
        "`positioning` receiver: no fix is latched",
        "`SEQ` stops, `AGE_MS` grows, `STATUS.VALID` clears after `STALE_MS` with `EVENTS.LOST`",
        "the positioning driver hands out no fix; the robot dead-reckons on its encoders. A "
        "robot that never had a fix stays unlocalised and does not broadcast",
    ),
    FaultEffect(
        "watchdog_expire",
        "`watchdog` count: expires at the end of the next control tick",
        "`STATUS.EXPIRED`, `EXPIRE_COUNT` + 1, every `pwmN.STATUS.SAFE_STOP`; pins at 0 and the "
        "act message's `watchdog_expired` for one control period",
        "nothing special: its next tick kicks as always, which re-arms the watchdog and ends the "
        "cut; the robot coasts for one period",
    ),
    FaultEffect(
        "tick_slow",
        "no register: every control tick takes `extra_ms` longer (CPU overload)",
        "nothing in the registers; in real time its loop timing counts every tick that ends more "
        "than a period after its deadline as a miss",
        "in real time its ticks run late, so the act messages and frames leave late; in "
        "lockstep the world waits for them, so only wall time slows",
    ),
    FaultEffect(
        "clear_registers",
        "every hook above released",
        "the registers as the IPs make them again; `COUNT` true at once",
        "carries on from where the faults left it",
    ),
)
"""One row per register fault, in the order of `swarm_config.faults.REGISTER_FAULTS`."""


def fault_label(fault: RegisterFault) -> str:
    """`name(field=value, ...)` without the robot: what telemetry and dashboards show."""
    fields = fault.model_dump(exclude={"fault", "robot"})
    if not fields:
        return fault.fault
    return f"{fault.fault}({', '.join(f'{k}={v}' for k, v in fields.items())})"


def _key(fault: RegisterFault) -> _FaultKey:
    """Faults with the same key act on the same thing: the newer replaces the older."""
    match fault:
        case EncoderStuckFault():
            return ("encoder_stuck", fault.wheel)
        case EncoderBitStuckFault():
            return ("encoder_bit_stuck", fault.wheel, fault.bit)
        case PwmStuckFault() | PwmSaturatedFault():
            return ("pwm", fault.wheel)
        case _:
            return (fault.fault,)


class RegisterFaults:
    """The register faults active in one fabric, applied to its IPs."""

    def __init__(self, fabric: Fabric) -> None:
        self._fabric = fabric
        self._active: dict[_FaultKey, RegisterFault] = {}
        self._tick_extra_s = 0.0

    @property
    def active(self) -> tuple[RegisterFault, ...]:
        """The faults in force, oldest first (a forced expiry until it has landed)."""
        return tuple(self._active.values())

    @property
    def labels(self) -> tuple[str, ...]:
        """`fault_label` of each active fault."""
        return tuple(fault_label(fault) for fault in self._active.values())

    @property
    def tick_extra_s(self) -> float:
        """How much longer every control tick takes (`tick_slow`), 0.0 without the fault."""
        return self._tick_extra_s

    def apply(self, fault: RegisterFault) -> None:
        """Put `fault` in force (`clear_registers`: release every fault)."""
        if isinstance(fault, ClearRegistersFault):
            self._active.clear()
        else:
            key = _key(fault)
            self._active.pop(key, None)
            self._active[key] = fault
        self._sync()

    def clear(self) -> None:
        """Release every fault."""
        self._active.clear()
        self._sync()

    def land_pending(self) -> None:
        """Let a forced watchdog expiry happen now: the end of a control tick, after the
        firmware's kick and before the pins are published."""
        if self._active.pop(("watchdog_expire",), None) is not None:
            self._fabric.watchdog.hw_force_expire()

    def _sync(self) -> None:
        """Every IP's fault inputs from the active set."""
        fabric = self._fabric
        faults = self._active.values()
        for wheel, qep in enumerate(fabric.qep):
            qep.hw_cut_lines(("encoder_stuck", wheel) in self._active)
            mask = bits = 0
            for fault in faults:
                if isinstance(fault, EncoderBitStuckFault) and fault.wheel == wheel:
                    mask |= 1 << fault.bit
                    bits |= fault.value << fault.bit
            qep.hw_force_count_bits(mask, bits)
        for wheel, pwm in enumerate(fabric.pwm):
            held = self._active.get(("pwm", wheel))
            if isinstance(held, PwmStuckFault):
                pwm.hw_hold_output(held.duty)
            elif isinstance(held, PwmSaturatedFault):
                pwm.hw_hold_output(float(held.sign))
            else:
                pwm.hw_hold_output(None)
        no_echo = any(isinstance(fault, SonarNoEchoFault) for fault in faults)
        for sonar in fabric.sonar:
            sonar.hw_block_echo(no_echo)
        fabric.positioning.hw_block_fixes(any(isinstance(f, FixCutFault) for f in faults))
        slow = self._active.get(("tick_slow",))
        self._tick_extra_s = slow.extra_ms / MS_PER_S if isinstance(slow, TickSlowFault) else 0.0

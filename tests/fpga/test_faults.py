"""Register faults: each one's effect read back through the bus and the pins, replacement of a
fault on the same output, and `clear_registers` leaving IPs that behave as if never faulted."""

from __future__ import annotations

from typing import Any, get_args

import numpy as np
import pytest

from robot_firmware.drivers import Drivers
from robot_firmware.fpga import Fabric, PositionFix
from robot_firmware.fpga.faults import FAULT_EFFECTS, fault_label
from robot_firmware.fpga.sonar import echo_time_s_for_range_m
from robot_firmware.fpga.watchdog import KICK_MAGIC
from swarm_config.faults import REGISTER_FAULT_ADAPTER, REGISTER_FAULTS, RegisterFault
from tests.fpga.register_sites import read_ok, write_ok

MS = 1_000_000
N_SONAR = 12
SPEED_WINDOW_NS = 10 * MS  # the QEP's reset window: 500_000 ticks at 50 MHz
PWM_PERIOD_TICKS = 2_500
DATA_READY, TIMEOUT = 0b001, 0b010
SAFE_STOP, SATURATED, ACTIVE = 0b001, 0b010, 0b100


def fault(name: str, **fields: Any) -> RegisterFault:
    return REGISTER_FAULT_ADAPTER.validate_python({"fault": name, "robot": "robot2", **fields})


def sense(
    fabric: Fabric,
    counts: tuple[int, int, int, int] = (0, 0, 0, 0),
    echo_s: float | None = None,
    fix: PositionFix | None = None,
) -> None:
    fabric.hw_apply_sense(counts, [echo_s] * len(fabric.sonar), fix)


def drive(fabric: Fabric, wheel: int, duty_ticks: int, reverse: bool = False) -> None:
    """What the motor driver writes for one wheel."""
    write_ok(fabric, f"pwm{wheel}", "DUTY_TICKS", duty_ticks)
    write_ok(fabric, f"pwm{wheel}", "CTRL", 0b11 if reverse else 0b01)


def test_every_register_fault_has_its_documented_effect() -> None:
    assert [effect.fault for effect in FAULT_EFFECTS] == [
        get_args(model.model_fields["fault"].annotation)[0] for model in REGISTER_FAULTS
    ]


def test_a_stuck_encoder_holds_its_count_and_reads_as_a_stopped_wheel() -> None:
    fabric = Fabric()
    sense(fabric, (0, 0, 0, 0))
    sense(fabric, (100, 100, 100, 100))
    fabric.tick(SPEED_WINDOW_NS)
    assert read_ok(fabric, "qep2", "SPEED") == 100
    fabric.faults.apply(fault("encoder_stuck", wheel=2))
    sense(fabric, (250, 250, 250, 250))
    fabric.tick(SPEED_WINDOW_NS)
    assert [read_ok(fabric, f"qep{w}", "COUNT") for w in range(4)] == [250, 250, 100, 250]
    assert read_ok(fabric, "qep2", "SPEED") == 0
    assert read_ok(fabric, "qep0", "SPEED") == 150
    fabric.faults.apply(fault("clear_registers"))
    sense(fabric, (300, 300, 300, 300))
    # The edges of the cut are lost: counting resumes from where the lines came back.
    assert read_ok(fabric, "qep2", "COUNT") == 150
    assert read_ok(fabric, "qep0", "COUNT") == 300


def test_a_stuck_count_bit_reads_forced_while_the_position_counts_on() -> None:
    fabric = Fabric()
    sense(fabric, (0, 0, 0, 0))
    sense(fabric, (5, 5, 5, 5))  # 0b101
    fabric.faults.apply(fault("encoder_bit_stuck", wheel=1, bit=1, value=1))
    assert read_ok(fabric, "qep1", "COUNT") == 0b111
    fabric.faults.apply(fault("encoder_bit_stuck", wheel=1, bit=0, value=0))
    assert read_ok(fabric, "qep1", "COUNT") == 0b110
    sense(fabric, (8, 8, 8, 8))  # 0b1000
    assert read_ok(fabric, "qep1", "COUNT") == 0b1010
    assert fabric.qep[1].hw_count() == 8
    assert read_ok(fabric, "qep0", "COUNT") == 8
    # The same bit again replaces its value.
    fabric.faults.apply(fault("encoder_bit_stuck", wheel=1, bit=1, value=0))
    assert read_ok(fabric, "qep1", "COUNT") == 0b1000
    assert len(fabric.faults.active) == 2
    fabric.faults.clear()
    assert read_ok(fabric, "qep1", "COUNT") == 8


def test_a_stuck_high_bit_reads_as_a_jump_to_the_encoder_driver() -> None:
    fabric = Fabric()
    drivers = Drivers.attach(fabric.bus, N_SONAR)
    sense(fabric, (0, 0, 0, 0))
    sense(fabric, (40, 40, 40, 40))
    assert drivers.encoders.read_counts().tolist() == [40, 40, 40, 40]
    fabric.faults.apply(fault("encoder_bit_stuck", wheel=3, bit=20, value=1))
    sense(fabric, (41, 41, 41, 41))
    jumped = drivers.encoders.read_counts()
    assert jumped.tolist() == [41, 41, 41, 41 + (1 << 20)]
    print(f"\nencoder_bit_stuck bit 20: the driver's count of wheel 3 jumps by {jumped[3] - 41}")


def test_sonar_with_no_echo_times_out_and_keeps_its_last_width() -> None:
    fabric = Fabric()
    echo_s = echo_time_s_for_range_m(1.0)
    sense(fabric, echo_s=echo_s)
    write_ok(fabric, "sonar4", "TRIGGER", 1)
    fabric.tick(10 * MS)
    assert read_ok(fabric, "sonar4", "EVENTS") == DATA_READY
    width = read_ok(fabric, "sonar4", "WIDTH_TICKS")
    fabric.faults.apply(fault("sonar_no_echo"))
    sense(fabric, echo_s=echo_s)
    write_ok(fabric, "sonar4", "TRIGGER", 1)
    fabric.tick(10 * MS)
    assert read_ok(fabric, "sonar4", "EVENTS") == 0  # still waiting: no echo comes
    fabric.tick(20 * MS)  # past TIMEOUT_TICKS (30 ms)
    assert read_ok(fabric, "sonar4", "EVENTS") == TIMEOUT
    assert read_ok(fabric, "sonar4", "WIDTH_TICKS") == width
    assert read_ok(fabric, "sonar4", "SAMPLES") == 1
    fabric.faults.apply(fault("clear_registers"))
    write_ok(fabric, "sonar4", "TRIGGER", 1)
    fabric.tick(10 * MS)
    assert read_ok(fabric, "sonar4", "EVENTS") == DATA_READY
    assert read_ok(fabric, "sonar4", "SAMPLES") == 2


def test_sonar_driver_sees_nothing_in_range_with_no_echo() -> None:
    fabric = Fabric()
    drivers = Drivers.attach(fabric.bus, N_SONAR)
    fabric.faults.apply(fault("sonar_no_echo"))
    sense(fabric, echo_s=echo_time_s_for_range_m(0.5))
    drivers.sonar.trigger_all()
    fabric.tick(31 * MS)
    gaps, fresh = drivers.sonar.poll()
    assert fresh
    assert np.all(np.isinf(gaps))


def test_a_stuck_pwm_holds_its_pins_whatever_the_registers_say() -> None:
    fabric = Fabric()
    drive(fabric, 2, 500)  # 0.2 forward
    assert fabric.hw_read_actuation().duty[2] == pytest.approx(0.2)
    fabric.faults.apply(fault("pwm_stuck", wheel=2, duty=-0.5))
    drive(fabric, 2, 2000)
    actuation = fabric.hw_read_actuation()
    assert actuation.duty == (0.0, 0.0, -0.5, 0.0)
    assert actuation.enabled[2]
    assert read_ok(fabric, "pwm2", "DUTY_TICKS") == 2000  # the write itself succeeded
    assert read_ok(fabric, "pwm2", "STATUS") == ACTIVE
    fabric.faults.apply(fault("clear_registers"))
    assert fabric.hw_read_actuation().duty[2] == pytest.approx(0.8)


def test_a_stuck_pwm_at_zero_drives_nothing_even_when_commanded() -> None:
    fabric = Fabric()
    fabric.faults.apply(fault("pwm_stuck", wheel=0, duty=0.0))
    drive(fabric, 0, 1250)
    assert fabric.hw_read_actuation().duty[0] == 0.0
    assert read_ok(fabric, "pwm0", "STATUS") == 0


def test_a_saturated_pwm_drives_full_duty_and_replaces_a_stuck_one() -> None:
    fabric = Fabric()
    fabric.faults.apply(fault("pwm_stuck", wheel=1, duty=0.3))
    fabric.faults.apply(fault("pwm_saturated", wheel=1, sign=-1))
    drive(fabric, 1, 100)
    assert fabric.hw_read_actuation().duty[1] == -1.0
    assert read_ok(fabric, "pwm1", "STATUS") == SATURATED | ACTIVE
    assert [f.fault for f in fabric.faults.active] == ["pwm_saturated"]
    fabric.faults.apply(fault("pwm_saturated", wheel=3))
    assert fabric.hw_read_actuation().duty == (0.0, -1.0, 0.0, 1.0)


def test_the_watchdog_cut_still_holds_a_stuck_pwm_low() -> None:
    fabric = Fabric()
    fabric.faults.apply(fault("pwm_saturated", wheel=0))
    fabric.tick(101 * MS)  # no kick within the reset timeout
    actuation = fabric.hw_read_actuation()
    assert actuation.watchdog_expired
    assert actuation.duty == (0.0,) * 4 and not actuation.any_enabled
    assert read_ok(fabric, "pwm0", "STATUS") == SAFE_STOP | SATURATED
    write_ok(fabric, "watchdog", "KICK", KICK_MAGIC)
    assert fabric.hw_read_actuation().duty[0] == 1.0


def test_a_cut_fix_latches_nothing_and_goes_stale() -> None:
    fabric = Fabric()
    sense(fabric, fix=PositionFix(1.0, 2.0, 0.5, stamp_ns=1))
    assert read_ok(fabric, "positioning", "SEQ") == 1
    assert read_ok(fabric, "positioning", "EVENTS") == 0b01  # NEW_FIX
    fabric.faults.apply(fault("fix_cut"))
    for stamp_ns in range(2, 12):
        sense(fabric, fix=PositionFix(3.0, 4.0, 0.0, stamp_ns=stamp_ns))
        fabric.tick(50 * MS)
    assert read_ok(fabric, "positioning", "SEQ") == 1
    assert read_ok(fabric, "positioning", "X_UM") == 1_000_000
    assert read_ok(fabric, "positioning", "AGE_MS") == 500
    assert read_ok(fabric, "positioning", "STATUS") == 0  # stale after STALE_MS
    assert read_ok(fabric, "positioning", "EVENTS") == 0b10  # LOST
    fabric.faults.apply(fault("clear_registers"))
    sense(fabric, fix=PositionFix(3.0, 4.0, 0.0, stamp_ns=12))
    assert read_ok(fabric, "positioning", "SEQ") == 2
    assert read_ok(fabric, "positioning", "STATUS") == 1


def test_a_forced_expiry_lands_at_the_end_of_the_tick_and_the_next_kick_ends_it() -> None:
    fabric = Fabric()
    drivers = Drivers.attach(fabric.bus, N_SONAR)
    drivers.motors.configure()
    drivers.watchdog.configure(100)
    drivers.motors.set_duty([0.5, 0.5, 0.5, 0.5])
    fabric.faults.apply(fault("watchdog_expire"))
    assert fabric.faults.labels == ("watchdog_expire",)
    drivers.watchdog.kick()  # the firmware's tick, before the fault lands
    assert not fabric.hw_read_actuation().watchdog_expired
    fabric.faults.land_pending()
    assert fabric.faults.active == ()
    actuation = fabric.hw_read_actuation()
    assert actuation.watchdog_expired and actuation.duty == (0.0,) * 4
    assert read_ok(fabric, "watchdog", "STATUS") == 0b01  # EXPIRED, not ARMED
    assert read_ok(fabric, "watchdog", "EXPIRE_COUNT") == 1
    assert read_ok(fabric, "watchdog", "REMAINING_US") == 0
    assert all(read_ok(fabric, f"pwm{w}", "STATUS") & SAFE_STOP for w in range(4))
    assert drivers.watchdog.expired()
    fabric.faults.land_pending()  # nothing pending: nothing more
    assert read_ok(fabric, "watchdog", "EXPIRE_COUNT") == 1
    drivers.watchdog.kick()  # the next tick re-arms it
    actuation = fabric.hw_read_actuation()
    assert not actuation.watchdog_expired and actuation.duty == (0.5,) * 4
    assert read_ok(fabric, "watchdog", "STATUS") == 0b10  # ARMED


def test_clearing_drops_a_forced_expiry_that_has_not_landed() -> None:
    fabric = Fabric()
    fabric.faults.apply(fault("watchdog_expire"))
    fabric.faults.apply(fault("clear_registers"))
    fabric.faults.land_pending()
    assert read_ok(fabric, "watchdog", "EXPIRE_COUNT") == 0


def test_a_slow_tick_changes_no_register_and_a_new_one_replaces_the_old() -> None:
    fabric = Fabric()
    before = fabric.bus.snapshot()
    fabric.faults.apply(fault("tick_slow", extra_ms=20))
    assert fabric.faults.tick_extra_s == pytest.approx(0.020)
    fabric.faults.apply(fault("tick_slow", extra_ms=5.5))
    assert fabric.faults.tick_extra_s == pytest.approx(0.0055)
    assert fabric.faults.labels == ("tick_slow(extra_ms=5.5)",)
    assert fabric.bus.snapshot() == before
    fabric.faults.clear()
    assert fabric.faults.tick_extra_s == 0.0


def every_fault() -> list[RegisterFault]:
    return [
        fault("encoder_stuck", wheel=0),
        fault("encoder_bit_stuck", wheel=1, bit=31, value=1),
        fault("sonar_no_echo"),
        fault("pwm_stuck", wheel=2, duty=0.7),
        fault("pwm_saturated", wheel=3, sign=-1),
        fault("fix_cut"),
        fault("watchdog_expire"),
        fault("tick_slow", extra_ms=3),
    ]


def run_inputs(fabric: Fabric, drivers: Drivers) -> list[Any]:
    """The same traffic on both sides of the IPs; what the pins and registers show after."""
    drivers.watchdog.configure(100)
    drivers.motors.configure()
    seen: list[Any] = []
    for step in range(1, 40):
        counts = (7 * step, -3 * step, 11 * step, step)
        fix = PositionFix(0.01 * step, 0.5, 0.1, stamp_ns=step // 5)
        sense(fabric, counts, echo_time_s_for_range_m(0.02 * step), fix)
        drivers.motors.set_duty([0.1, -0.2, 0.3 * (-1) ** step, 0.4])
        if step % 3 == 0:
            drivers.sonar.trigger_all()
        drivers.watchdog.kick()
        fabric.faults.land_pending()
        fabric.tick(10 * MS)
        seen.append((fabric.hw_read_actuation(), drivers.encoders.read_counts().tolist()))
    seen.append(fabric.bus.snapshot())
    return seen


def test_cleared_faults_leave_ips_that_behave_as_if_never_faulted() -> None:
    faulted, fresh = Fabric(), Fabric()
    for each in every_fault():
        faulted.faults.apply(each)
    assert len(faulted.faults.active) == 8
    assert faulted.faults.labels[1] == "encoder_bit_stuck(wheel=1, bit=31, value=1)"
    faulted.faults.apply(fault("clear_registers"))
    assert faulted.faults.active == () and faulted.faults.tick_extra_s == 0.0
    assert faulted.bus.snapshot() == fresh.bus.snapshot()
    assert run_inputs(faulted, Drivers.attach(faulted.bus, N_SONAR)) == run_inputs(
        fresh, Drivers.attach(fresh.bus, N_SONAR)
    )


def test_faults_change_what_the_same_traffic_shows() -> None:
    """The comparison above can fail: with the faults in force the traces differ."""
    faulted, fresh = Fabric(), Fabric()
    for each in every_fault():
        faulted.faults.apply(each)
    faulted_trace = run_inputs(faulted, Drivers.attach(faulted.bus, N_SONAR))
    fresh_trace = run_inputs(fresh, Drivers.attach(fresh.bus, N_SONAR))
    assert faulted_trace[-2] != fresh_trace[-2]
    assert faulted_trace[-1] != fresh_trace[-1]


def test_labels_name_the_fault_and_its_parameters_without_the_robot() -> None:
    assert fault_label(fault("pwm_stuck", wheel=1, duty=0.5)) == "pwm_stuck(wheel=1, duty=0.5)"
    assert fault_label(fault("fix_cut")) == "fix_cut"

"""The HPS firmware of one robot: the 5C loop over the FPGA bus (DESIGN.md §4).

Every 10 ms `control_tick` runs the five levels in order:

    1 connection     read the QEP counts, the sonar ring and the positioning receiver through
                     the drivers (bus accesses only; no other way to the sensors exists)
    2 conversion     odometry and fix fusion, sonar gaps to obstacle points
    3 cyber          peers' broadcast states from the radio; desired pose (trajectory or
                     eqs. 17-21); APF (eqs. 22-25)
    4 cognition      fuzzy-scheduled gains (Table 2) and the redundant PID law (eq. 14)
    5 configuration  wheel speeds to PWM duty registers, watchdog kick, radio broadcast

Levels 2-4 are `control_step`, the same function the batch simulator runs for thousands of
robots at once; here its batch shape is ().  Radio frames arrive through `receive` between
ticks; malformed, stale, replayed or unauthenticated ones are dropped and counted by the frame
decoder and never reach the control law; a frame whose sender has no fix yet (`localised`
False) is not used either, and a robot with no fix broadcasts nothing.

When the sense messages stop (the scheduler's `SafeStop`), `safe_stop` turns the motors off
through the motor driver and stops kicking the watchdog, so the watchdog IP cuts the PWM at
its timeout even if the driver's writes were lost.  The first tick after the gap (`resume`,
or a tick more than `RESUME_GAP_PERIODS` after the previous one) starts from a fresh control
state: it re-localises from the next fix, its PID and avoidance state start from zero, and peer
states outside the decoder's age window are dropped.  On a new world epoch (`new_world_epoch`:
the world restarted and its clock jumped) every peer state and replay window goes, whatever its
stamp.  Time is an argument (`now_ns`); the class opens no socket and reads no clock, so a test
can run it against a fabric model in one process.

Who leads is not fixed by the mission: `Leadership` (robot_firmware/leadership.py) hears the
term and role of every accepted frame (and the peers' liveliness, `set_peer_alive`; not counted
in lockstep, `lockstep`), and each tick gives the control step its role (leader or follower),
its slot relative to the acting leader (`slot_of`; while rejoining, `rejoin_slot`) and which
peer that leader is.  Frames carry the robot's term and whether it leads.

A peer that is not live (its token gone, or silent past the leader time-out) has stopped: a
dead robot's body is braked where it lost power and stays an obstacle (DESIGN.md §7).  It is
held where its last broadcast state coasts to in `stopped_coast_s`, never goes stale, and is
marked stopped for the avoidance (`ControlInputs.peer_stopped`), until it is heard again.  A
peer other than the leader that has only been silent for longer than `stopped_coast_s` is not
extrapolated beyond that either.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from robot_firmware.control.controller import (
    ControllerParams,
    ControllerState,
    ControlOutputs,
    OneRobotControl,
    RobotRole,
    sonar_beam_points,
)
from robot_firmware.control.fuzzy import FuzzyRuleBase
from robot_firmware.control.trajectories import Trajectory
from robot_firmware.drivers import Drivers
from robot_firmware.leadership import (
    Leadership,
    LeadershipParams,
    handover_offset,
    rejoin_slot,
    slot_of,
)
from robot_firmware.net.frames import (
    NO_RUN_ID,
    FrameDecoder,
    RadioFrame,
    Role,
    encode,
    initial_sequence,
    next_sequence,
)
from robot_firmware.sonar_health import SonarHealth
from swarm_config.scenario import Scenario, ScenarioError

FloatArray = NDArray[np.float64]
NS_PER_S = 1_000_000_000
RESUME_GAP_PERIODS = 10
"""A tick this many control periods (or more) after the previous one, or before it, starts
from fresh state as after `Firmware.resume` (the tick scheduler's sense time-out is as long):
a real-time robot continued after a freeze may run a tick on a stale sense message first, and
only the next one on the world's time."""


@dataclass(frozen=True)
class RobotMission:
    """What one robot is told about its task: who it is, its role, and how to steer."""

    name: str
    index: int
    names: tuple[str, ...]
    is_leader: bool
    slot_distance_m: float
    slot_angle_rad: float
    trajectory: Trajectory
    params: ControllerParams
    rule_base: FuzzyRuleBase
    broadcast_rate_hz: float = 20.0
    sonar_rate_hz: float = 20.0
    sonar_max_range_m: float = 3.0
    """The farthest gap the sonar ring reads (robot_firmware/sonar_health.py)."""
    watchdog_timeout_ms: int = 100
    designated_leader: int | None = None
    """Index of the scenario's leader (None: this robot if `is_leader`, else robot 0)."""
    slots: tuple[tuple[float, float], ...] = ()
    """Every robot's scenario slot (distance_m, angle_rad), by index; the leader's (0, 0).
    Empty: only this robot's own slot is known."""
    leadership: LeadershipParams = field(default_factory=LeadershipParams)

    @classmethod
    def from_scenario(cls, scenario: Scenario, name: str, rule_base: FuzzyRuleBase) -> RobotMission:
        """What robot `name` is told at boot: its index, role, slot, trajectory, parameters."""
        names = scenario.robot_names
        if name not in names:
            raise ScenarioError(f"no robot named {name!r} in scenario {scenario.name!r}: {names}")
        index = names.index(name)
        spec = scenario.robots[index]
        slots = tuple(
            (r.slot.distance_m, math.radians(r.slot.angle_deg)) if r.slot else (0.0, 0.0)
            for r in scenario.robots
        )
        return cls(
            name=name,
            index=index,
            names=names,
            is_leader=spec.role == "leader",
            slot_distance_m=spec.slot.distance_m if spec.slot else 0.0,
            slot_angle_rad=math.radians(spec.slot.angle_deg) if spec.slot else 0.0,
            trajectory=scenario.trajectory.build(),
            params=scenario.controller_params(),
            rule_base=rule_base,
            broadcast_rate_hz=scenario.radio.broadcast_rate_hz,
            sonar_rate_hz=scenario.sensors.sonar.rate_hz,
            sonar_max_range_m=scenario.sensors.sonar.max_range_m,
            designated_leader=scenario.leader_index,
            slots=slots,
        )

    @property
    def sonar_count(self) -> int:
        return len(self.params.sonar_beam_angles_rad)

    @property
    def leader_index(self) -> int:
        """The scenario's (designated) leader."""
        if self.designated_leader is not None:
            return self.designated_leader
        return self.index if self.is_leader else 0

    @property
    def slot_table(self) -> tuple[tuple[float, float], ...]:
        """`slots`, or one built from this robot's own slot when the mission has none."""
        if self.slots:
            return self.slots
        own = (self.slot_distance_m, self.slot_angle_rad)
        return tuple(own if i == self.index else (0.0, 0.0) for i in range(len(self.names)))


@dataclass(frozen=True)
class TickReport:
    """What one control tick did: the control law's outputs and the frame to broadcast."""

    outputs: ControlOutputs
    frame: bytes | None
    sonar_fresh: bool
    fix_fresh: bool


class Firmware:
    """One robot's control software, reaching its hardware only through `drivers`."""

    def __init__(
        self,
        mission: RobotMission,
        drivers: Drivers,
        key: bytes,
        swarm_hash: int = 0,
        run_id: bytes = NO_RUN_ID,
    ) -> None:
        """key: the frame key (`derive_frame_key`); run_id: the run's id, carried in and
        required of every frame (robot_firmware/net/frames.py)."""
        self.mission = mission
        self.drivers = drivers
        self._key = key
        self._swarm_hash = swarm_hash
        self._run_id = run_id
        n = len(mission.names)
        self.decoder = FrameDecoder(key, own_id=mission.index, swarm_hash=swarm_hash, run_id=run_id)
        self.control = OneRobotControl(mission.params, n, mission.rule_base)
        """The control step's arrays, made once: each tick writes its inputs there."""
        self.role: RobotRole = self.control.role
        """This tick's role and slot (views: `_take_role` writes them in place)."""
        self._set_role(mission.is_leader, mission.slot_distance_m, mission.slot_angle_rad)
        self.rules = mission.rule_base
        """One scheduler for the three axes."""
        self.peer_pose = np.zeros((n, 3))
        self.peer_rate = np.zeros((n, 3))
        self.peer_stamp_s = np.full(n, -np.inf)
        self.peer_is_leader = np.zeros(n, dtype=bool)
        self.peer_down = np.zeros(n, dtype=bool)
        """Peers that are not live: stopped bodies where they coasted to, until heard again."""
        self.leadership: Leadership | None = None
        """Created at the first frame or tick, when the robot first knows the time."""
        self.lockstep = False
        """Whether the world runs in lockstep (the runtime sets it from the sense messages):
        then the peers' liveliness tokens are kept but do not count (`Leadership.use_tokens`),
        so failover depends only on frames and their simulation times."""
        self.tokens_suspended = False
        """Whether the peers' liveliness tokens do not count for now: the runtime's loop
        stalled lately (robot_firmware/tick_scheduler.py `LoopStallWatch`)."""
        self._handover: tuple[float, tuple[float, float]] | None = None
        """(time, offset from the trajectory) of taking over the lead while driving."""
        self._handover_pending = False
        """Whether a leader starts its reference from where it is at its next localised tick
        (it held still meanwhile), as on taking over the lead."""
        self.sonar_health = SonarHealth.for_range(mission.sonar_max_range_m)
        """Whether the sonar ring still hears; while it does not, the robot holds still."""
        self._followed: int | None = None
        """The acting leader of the previous tick (None: none, or no tick yet)."""
        self._rejoin_pending = False
        """Whether the next tick with a known leader starts a rejoin (`_rejoin_slot`)."""
        self._rejoin: tuple[float, tuple[float, float]] | None = None
        """(time, (distance_m, angle_rad) relative to the leader) where the rejoin under way
        started."""
        self.sonar_gap_m = np.full(mission.sonar_count, np.inf)
        self.fix_pose = np.zeros(3)
        self._sequence: int | None = None
        self._broadcast_period_ns = round(NS_PER_S / mission.broadcast_rate_hz)
        self._sonar_period_ns = round(NS_PER_S / mission.sonar_rate_hz)
        self._next_broadcast_ns = 0
        self._next_sonar_ns = 0
        self.ticks = 0
        self.frames_sent = 0
        self.unlocalised_peer_frames = 0
        """Authentic frames refused because their sender had no fix (`localised` False)."""
        self.safe_stopped = False
        """Whether the motors are held off for want of sense messages (`safe_stop`)."""
        self._fresh_state_pending = False
        self._last_tick_ns: int | None = None
        self._resume_gap_ns = round(RESUME_GAP_PERIODS * mission.params.control_period_s * NS_PER_S)

    @property
    def state(self) -> ControllerState:
        """The control state the next tick starts from (views into `control`'s arrays)."""
        return self.control.state

    def sonar_echo_points_m(self) -> tuple[tuple[float, float], ...]:
        """Where the last sonar sweep puts echoes, in the world, seen from the estimated pose:
        one (x, y) per transducer that heard one (all echoes, not only those the APF uses)."""
        heard = np.isfinite(self.sonar_gap_m)
        points = sonar_beam_points(
            self.state.estimator.pose, np.where(heard, self.sonar_gap_m, 0.0), self.mission.params
        )
        return tuple((x, y) for x, y in points[heard].tolist())

    def set_rule_base(self, rule_base: FuzzyRuleBase) -> None:
        """Use another fuzzy scheduler from the next tick on (call between ticks)."""
        self.rules = rule_base
        self.control.set_rule_base(rule_base)

    def boot(self, tick_fabric: Callable[[int], None], pll_timeout_ns: int = 1_000_000) -> None:
        """Identify the fabric, wait for the PLL, arm the motors and the watchdog."""
        self.drivers.system.identify()
        self.drivers.system.wait_for_pll_lock(tick_fabric, pll_timeout_ns)
        self.drivers.motors.configure()
        self.drivers.watchdog.configure(self.mission.watchdog_timeout_ms)

    def receive(self, data: bytes, now_ns: int) -> bool:
        """Take one radio frame; returns whether it was accepted into the peer table."""
        frame = self.decoder.decode(data, now_ns)
        if frame is None or frame.sender_id >= len(self.mission.names):
            return False
        claims_lead = frame.role == Role.LEADER
        self.leadership_at(now_ns).hear(frame.sender_id, frame.term, claims_lead, now_ns / NS_PER_S)
        if not frame.localised:
            self.unlocalised_peer_frames += 1
            return False
        i = frame.sender_id
        self.peer_pose[i] = (frame.x_m, frame.y_m, frame.theta_rad)
        self.peer_rate[i] = (frame.xdot_mps, frame.ydot_mps, frame.thetadot_radps)
        self.peer_stamp_s[i] = frame.timestamp_ns / NS_PER_S
        self.peer_down[i] = False
        self.peer_is_leader[i] = claims_lead
        return True

    def leadership_at(self, now_ns: int) -> Leadership:
        """The election state, made on first use with `now_ns` as the boot time."""
        if self.leadership is None:
            m = self.mission
            self.leadership = Leadership(
                index=m.index,
                count=len(m.names),
                designated_leader=m.leader_index,
                boot_s=now_ns / NS_PER_S,
                params=m.leadership,
            )
        return self.leadership

    @property
    def is_leader(self) -> bool:
        """Whether this robot leads now (before its first tick: whether it is designated to)."""
        if self.leadership is None:
            return self.mission.is_leader
        return self.leadership.is_leader

    def set_peer_alive(self, peer: str, alive: bool, now_ns: int) -> None:
        """The runtime saw robot `peer`'s liveliness token appear or go (then the peer is held
        as a stopped body at its last broadcast pose); unknown names are ignored."""
        if peer in self.mission.names:
            index = self.mission.names.index(peer)
            self.leadership_at(now_ns).set_alive(index, alive, now_ns / NS_PER_S)

    def _take_role(self, now_ns: int) -> None:
        """This tick's role and slot, and which peer leads (levels 3-4 read them)."""
        leadership = self.leadership_at(now_ns)
        t_s = now_ns / NS_PER_S
        first_tick = self.ticks == 0
        leadership.use_tokens = not self.lockstep and not self.tokens_suspended
        leadership.update(t_s)
        acting = leadership.acting_leader(t_s)
        m = self.mission
        if acting != self._followed and not (first_tick and leadership.boot_s <= 0.0):
            # A new leader to follow, or one again after none: rejoin from where it is.  Not at
            # the run's start, where every robot drives straight to its slot (the paper's run).
            self._rejoin_pending = True
        self._followed = acting
        distance_m, angle_rad = slot_of(m.index, acting, m.leader_index, m.slot_table)
        if acting is None or acting == m.index:
            self._rejoin = None
        else:
            distance_m, angle_rad = self._rejoin_slot(t_s, acting, distance_m, angle_rad)
        self._set_role(leadership.is_leader, distance_m, angle_rad)
        self.peer_is_leader[:] = False
        if acting is not None and acting != m.index:
            self.peer_is_leader[acting] = True
        # A peer that is not live has stopped (DESIGN.md §7: a power cut; the world brakes its
        # body) and stays an obstacle, never stale, until it is heard again: held where its
        # last broadcast state coasts to in `stopped_coast_s`.
        live = leadership.live_flags(t_s)
        down = [
            not alive and math.isfinite(stamp_s)
            for alive, stamp_s in zip(live, self.peer_stamp_s.tolist(), strict=True)
        ]
        if any(down):
            coast_s = m.leadership.stopped_coast_s
            was_down = self.peer_down.tolist()
            for peer, is_down in enumerate(down):
                if not is_down:
                    continue
                if not was_down[peer]:
                    self.peer_pose[peer] += self.peer_rate[peer] * coast_s
                    self.peer_rate[peer] = 0.0
                self.peer_stamp_s[peer] = t_s
        self.peer_down[:] = down

    def _set_role(self, is_leader: bool, slot_distance_m: float, slot_angle_rad: float) -> None:
        role = self.role
        role.is_leader[...] = is_leader
        role.slot_distance_m[...] = slot_distance_m
        role.slot_angle_rad[...] = slot_angle_rad

    def _coasted_peers(self, t_s: float) -> FloatArray:
        """The peer table into the control step's inputs, and their poses: a peer other than
        the leader silent for longer than `stopped_coast_s` is taken where its last state
        coasts to in that time, not extrapolated further (a frozen or dead robot's body has
        stopped by then; the leader's last state still places the followers' slots until it
        is lost)."""
        inputs = self.control.inputs
        pose, rate, stamp_s = inputs.peer_pose, inputs.peer_rate, inputs.peer_stamp_s
        pose[...] = self.peer_pose
        rate[...] = self.peer_rate
        stamp_s[:] = self.peer_stamp_s
        coast_s = self.mission.leadership.stopped_coast_s
        timeout_s = self.mission.params.peer_timeout_s
        for peer, peer_stamp_s in enumerate(self.peer_stamp_s.tolist()):
            age_s = t_s - peer_stamp_s
            if coast_s < age_s <= timeout_s and not self.peer_is_leader[peer]:
                pose[peer] += rate[peer] * coast_s
                rate[peer] = 0.0
                stamp_s[peer] = t_s
        return pose

    def _rejoin_slot(
        self, t_s: float, leader: int, distance_m: float, angle_rad: float
    ) -> tuple[float, float]:
        """The slot (distance_m, angle_rad) to steer to while rejoining the formation.

        A follower that starts following a leader after the run's start (booted late, resumed
        after a gap, or re-referenced to a new leader) is seldom near its slot, and the control
        law's pull on a far reference overpowers the avoidance.  So its slot starts where the
        robot is, relative to the leader (eq. 17 inverted), and swings round to the real one at
        `rejoin_speed_mps` (`rejoin_slot`)."""
        if self._rejoin_pending:
            est = self.state.estimator
            age_s = t_s - self.peer_stamp_s[leader]
            if not bool(est.localised) or not 0.0 <= age_s <= self.mission.params.peer_timeout_s:
                return distance_m, angle_rad  # inactive until both poses are known
            leader_pose = self.peer_pose[leader] + self.peer_rate[leader] * age_s
            dx = float(est.pose[0] - leader_pose[0])
            dy = float(est.pose[1] - leader_pose[1])
            here = (math.hypot(dx, dy), math.atan2(dy, dx) - float(leader_pose[2]))
            self._rejoin = (t_s, here)
            self._rejoin_pending = False
        if self._rejoin is None:
            return distance_m, angle_rad
        started_s, start = self._rejoin
        speed_mps = self.mission.leadership.rejoin_speed_mps
        slot = rejoin_slot(start, (distance_m, angle_rad), t_s - started_s, speed_mps)
        if slot == (distance_m, angle_rad):
            self._rejoin = None
        return slot

    def _handed_over(
        self, was_leader: bool, t_s: float, pose: FloatArray, rate: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """The trajectory as this robot's reference: offset after it took over the lead while
        it was driving in the formation (`handover_offset`)."""
        est = self.state.estimator
        if not bool(self.role.is_leader):
            self._handover = None
            return pose, rate
        if (not was_leader or self._handover_pending) and bool(est.localised):
            start = (float(est.pose[0] - pose[0]), float(est.pose[1] - pose[1]))
            self._handover = (t_s, start)
            self._handover_pending = False
        if self._handover is None:
            return pose, rate
        started_s, offset0_m = self._handover
        speed_mps = self.mission.leadership.handover_speed_mps
        offset_m, offset_rate_mps = handover_offset(offset0_m, t_s - started_s, speed_mps)
        if offset_m == (0.0, 0.0):
            self._handover = None
            return pose, rate
        pose[:2] += offset_m
        rate[:2] += offset_rate_mps
        return pose, rate

    def safe_stop(self) -> None:
        """No sense messages: duty 0 and outputs disabled through the motor driver, and no more
        watchdog kicks (its IP cuts the PWM at its timeout).  Repeating it changes nothing."""
        self.drivers.motors.disable()
        self.safe_stopped = True

    def resume(self, now_ns: int) -> None:
        """Sense messages are back after a gap: drop what went stale before the next tick.

        Peer states stamped outside the decoder's window around `now_ns` are forgotten, the
        broadcast and sonar schedules restart, and the next `control_tick` starts from a fresh
        control state (unlocalised until the next fix; encoders counted from that tick on)."""
        decoder = self.decoder
        age_ns = now_ns - self.peer_stamp_s * NS_PER_S
        stale = (age_ns > decoder.max_age_ns) | (age_ns < -decoder.max_future_ns)
        self.peer_stamp_s[stale] = -np.inf
        self.sonar_gap_m[:] = np.inf
        self._next_broadcast_ns = 0
        self._next_sonar_ns = 0
        self._fresh_state_pending = True
        self._rejoin_pending = True
        self._last_tick_ns = now_ns
        self.leadership_at(now_ns).resume(now_ns / NS_PER_S)

    def new_world_epoch(self, now_ns: int) -> None:
        """The world restarted and its clock jumped (to `now_ns`, backwards or forwards): every
        peer state and every replay window from before the jump is void, and so are the
        schedules (`resume`).  The frame decoder starts afresh; its counters carry on."""
        self.peer_stamp_s[:] = -np.inf
        counters = self.decoder.counters
        self.decoder = FrameDecoder(
            self._key, own_id=self.mission.index, swarm_hash=self._swarm_hash, run_id=self._run_id
        )
        self.decoder.counters = counters
        self.leadership_at(now_ns).new_epoch(now_ns / NS_PER_S)
        self.resume(now_ns)

    def control_tick(self, now_ns: int) -> TickReport:
        """Run the 5C levels once at time now_ns (after a jump of the tick clock: on fresh
        state, as after `resume`)."""
        d = self.drivers
        t_s = now_ns / NS_PER_S
        last_ns, self._last_tick_ns = self._last_tick_ns, now_ns
        if last_ns is not None and not 0 <= now_ns - last_ns <= self._resume_gap_ns:
            self.resume(now_ns)
        # Level 1: connection.
        counts = d.encoders.read_counts()
        control = self.control
        if self._fresh_state_pending:
            self._fresh_state_pending = False
            control.reset(counts)
        fix = d.positioning.read_fix()
        if fix is not None:
            self.fix_pose = np.array([fix.x_m, fix.y_m, fix.heading_rad])
        gaps, sonar_fresh = d.sonar.poll()
        if sonar_fresh:
            self.sonar_gap_m = gaps
        if now_ns >= self._next_sonar_ns:
            d.sonar.trigger_all()
            self._next_sonar_ns = now_ns + self._sonar_period_ns
        # Levels 2-4: the shared control step, in this tick's role.
        was_leader = bool(self.role.is_leader)
        self._take_role(now_ns)
        reference_pose, reference_rate = self.mission.trajectory.evaluate(t_s)
        reference_pose, reference_rate = self._handed_over(
            was_leader, t_s, reference_pose, reference_rate
        )
        peer_pose = self._coasted_peers(t_s)
        if sonar_fresh:
            self._check_sonar(gaps, t_s, peer_pose)
        inputs = control.inputs
        inputs.encoder_counts[:] = counts
        inputs.fix_pose[:] = self.fix_pose
        inputs.fix_valid[...] = fix is not None
        inputs.sonar_range_m[:] = self.sonar_gap_m
        np.isfinite(self.peer_stamp_s, out=inputs.peer_valid)
        inputs.peer_is_leader[:] = self.peer_is_leader
        inputs.reference_pose[:] = reference_pose
        inputs.reference_rate[:] = reference_rate
        control.peer_stopped[:] = self.peer_down
        outputs = control.step(t_s, sonar_fresh)
        # Level 5: configuration (held still while the sonar ring is deaf).
        if self.sonar_health.failed:
            d.motors.set_duty((0.0, 0.0, 0.0, 0.0))
        else:
            d.motors.set_duty(outputs.duty)
        d.watchdog.kick()
        self.safe_stopped = False
        frame = None
        if now_ns >= self._next_broadcast_ns and bool(self.state.estimator.localised):
            self._next_broadcast_ns = now_ns + self._broadcast_period_ns
            frame = self._broadcast(now_ns)
        self.ticks += 1
        return TickReport(
            outputs=outputs, frame=frame, sonar_fresh=sonar_fresh, fix_fresh=fix is not None
        )

    def _check_sonar(self, gaps_m: FloatArray, t_s: float, peer_pose: FloatArray) -> None:
        """A fresh sweep against the peers known now (robot_firmware/sonar_health.py).  When
        the ring hears again after a failure, the robot drives on from fresh control state
        (re-localised, its rejoin or its leader's reference starting from where it is)."""
        est = self.state.estimator
        evidence: list[float] = []
        if bool(est.localised):
            params = self.mission.params
            x_m, y_m = est.pose[:2].tolist()
            for peer, (px_m, py_m) in enumerate(peer_pose[:, :2].tolist()):
                stamp_s = float(self.peer_stamp_s[peer])
                if math.isfinite(stamp_s) and t_s - stamp_s <= params.peer_timeout_s:
                    gap_m = math.hypot(px_m - x_m, py_m - y_m) - 2.0 * params.body_radius_m
                    evidence.append(gap_m)
        was_failed = self.sonar_health.failed
        if self.sonar_health.sweep(gaps_m, evidence) == was_failed:
            return
        if was_failed:
            self._fresh_state_pending = True
            self._rejoin_pending = True
            self._handover_pending = True

    def _broadcast(self, now_ns: int) -> bytes:
        self._sequence = (
            initial_sequence(now_ns) if self._sequence is None else next_sequence(self._sequence)
        )
        est = self.state.estimator
        pose = est.pose
        rate = est.rate
        frame = RadioFrame(
            role=Role.LEADER if self.is_leader else Role.FOLLOWER,
            sender_id=self.mission.index,
            sequence=self._sequence,
            timestamp_ns=now_ns,
            x_m=float(pose[0]),
            y_m=float(pose[1]),
            theta_rad=float(pose[2]),
            xdot_mps=float(rate[0]),
            ydot_mps=float(rate[1]),
            thetadot_radps=float(rate[2]),
            localised=bool(est.localised),
            swarm_hash=self._swarm_hash,
            run_id=self._run_id,
            term=self.leadership_at(now_ns).term,
        )
        self.frames_sent += 1
        return encode(frame, self._key)

"""The batch simulator's tick loop, compiled: many control ticks of B runs x N robots per call.

`run_ticks` does, tick after tick, what services/sim/batch.py describes, calling the same
compiled kernels the world process and the firmware call one at a time:

    deliver     frames due by now move into the receivers' peer tables (newest stamp wins)
    sense       encoders (`world.physics.encoder_count`) every tick; a positioning fix
                (`world.sensors.fix_axis`) and a sonar sweep (`world.sensors.sonar_reading`)
                when due
    control     `robot_firmware.control.controller.control_robots` for every robot at once
    metrics     `world.metrics.accumulate_samples` for every run, on the accumulator's arrays
    broadcast   the robots whose broadcast is due meet the radio medium (`world.radio.
                next_link_state`, `link_delivery`) and their frames enter the ring
    bodies      `world.physics.advance_bodies` for all robots per sub-step, `push_apart` per run

Every random number is drawn beforehand in numpy, in bulk for the chunk of ticks, from the
same stream and in the same order as the tick-by-tick form draws them (tests/world/oracle.py,
`run_batch_oracle`); a bulk draw of a numpy generator equals the same draws made one tick at a
time.  Rows are run-major: row r = b·N + i is robot i of run b.  Runs that share their noise
(common random numbers) read the draws of noise element 0.

The controller's state lives in two sets of arrays that the ticks use in turn (the kernel reads
one set and writes the other).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from robot_firmware.control.controller import control_robots
from world.metrics import accumulate_samples
from world.physics import advance_bodies, encoder_count, push_apart
from world.radio import link_delivery, next_link_state
from world.sensors import fix_axis, sonar_reading

FloatArray = NDArray[np.float64]


@njit(cache=True)
def _deliver(
    t_s: float, radio: tuple, peers: tuple, robots: int, first_world: int, stop_world: int
) -> None:
    """Frames due by t_s into the peer tables of runs first_world .. stop_world - 1; a receiver
    keeps the newest stamp per sender."""
    payload, stamp_s, arrival_s, pending, _next_slot, delivered = radio
    peer_pose, peer_rate, peer_stamp_s = peers
    slots = arrival_s.shape[0]
    for b in range(first_world, stop_world):
        for tx in range(robots):
            for rx in range(robots):
                best = -1
                best_stamp = -math.inf
                for q in range(slots):
                    if pending[q, b, tx, rx] and arrival_s[q, b, tx, rx] <= t_s:
                        pending[q, b, tx, rx] = False
                        delivered[b] += 1
                        if stamp_s[q, tx] > best_stamp:
                            best = q
                            best_stamp = stamp_s[q, tx]
                r = b * robots + rx
                if best >= 0 and best_stamp > peer_stamp_s[r, tx]:
                    for a in range(3):
                        peer_pose[r, tx, a] = payload[best, b, tx, a]
                        peer_rate[r, tx, a] = payload[best, b, tx, 3 + a]
                    peer_stamp_s[r, tx] = best_stamp


@njit(cache=True)
def _broadcast(
    k: int,
    t_s: float,
    every: int,
    pose: FloatArray,
    link_bad: NDArray[np.bool_],
    link: tuple,
    uniforms: FloatArray,
    offset: int,
    radio: tuple,
    estimate: tuple,
    first_world: int,
    stop_world: int,
) -> int:
    """Frames of the robots due at tick k, in runs first_world .. stop_world - 1, meet the links,
    from the positions they are sent from, and enter the ring; returns the offset of the next
    tick's uniforms.  The ring's slots and stamps, and shared links' states (one noise element
    for all runs), are the same for every run: a caller that splits the runs gives each part a
    copy of them."""
    payload, stamp_s, arrival_s, pending, next_slot, _delivered = radio
    latency_ms, jitter_ms, loss, burst, good_to_bad, bad_to_good, loss_good, loss_bad, range_m = (
        link
    )
    est_pose, est_rate = estimate
    worlds, robots = pose.shape[0], pose.shape[1]
    noise_worlds = link_bad.shape[0]
    senders = 0
    for i in range(robots):
        if (k + i) % every == 0:
            senders += 1
    if senders == 0:
        return offset
    block = noise_worlds * senders * robots
    slots = arrival_s.shape[0]
    measure = math.isfinite(range_m)
    per_run_noise = noise_worlds == worlds
    for b in range(first_world, stop_world):
        nb = b if per_run_noise else 0
        s = 0
        for i in range(robots):
            if (k + i) % every != 0:
                continue
            slot = next_slot[i] % slots
            r = b * robots + i
            for a in range(3):
                payload[slot, b, i, a] = est_pose[r, a]
                payload[slot, b, i, 3 + a] = est_rate[r, a]
            for j in range(robots):
                at = offset + (nb * senders + s) * robots + j
                u_state = uniforms[at + 2 * block] if burst else 0.0
                bad = next_link_state(u_state, link_bad[nb, i, j], burst, good_to_bad, bad_to_good)
                length_m = 0.0
                if measure:
                    length_m = math.hypot(
                        pose[b, i, 0] - pose[b, j, 0], pose[b, i, 1] - pose[b, j, 1]
                    )
                ok, delay_s = link_delivery(
                    uniforms[at], uniforms[at + block], bad, burst, loss, loss_good, loss_bad,
                    False, length_m, range_m, latency_ms, jitter_ms,
                )  # fmt: skip
                arrival_s[slot, b, i, j] = t_s + delay_s
                pending[slot, b, i, j] = ok and j != i
            s += 1
    s = 0
    for i in range(robots):
        if (k + i) % every != 0:
            continue
        stamp_s[next_slot[i] % slots, i] = t_s
        next_slot[i] += 1
        for nb in range(first_world, stop_world) if per_run_noise else range(noise_worlds):
            for j in range(robots):
                at = offset + (nb * senders + s) * robots + j
                u_state = uniforms[at + 2 * block] if burst else 0.0
                link_bad[nb, i, j] = next_link_state(
                    u_state, link_bad[nb, i, j], burst, good_to_bad, bad_to_good
                )
        s += 1
    return offset + (3 if burst else 2) * block


@njit(cache=True, nogil=True)
def run_ticks(
    first_tick: int,
    ticks: int,
    first_world: int,
    stop_world: int,
    schedule: tuple,
    reference: tuple,
    world: tuple,
    world_constants: tuple,
    controller: tuple,
    radio: tuple,
    link: tuple,
    metrics: tuple,
    draws: tuple,
    trace: tuple,
    record: bool,
) -> None:
    """Ticks first_tick .. first_tick + ticks - 1 of runs first_world .. stop_world - 1; every
    array is updated in place, in those runs' rows only, but for what all runs share: the
    radio ring's slots and stamps, shared links' states, the sonar targets (`centres`), the
    flags `contacts_known` and `previous_known` and the metrics' scratch.  Runs are independent
    of each other, so parts of a batch run on threads of their own (the function releases the
    GIL), each with its own copy of what is shared, and give the same results bit for bit.

    schedule: control period, broadcast, fix and sonar periods in ticks, body sub-steps;
    reference: the trajectory's pose and rate (ticks, 3); draws: this chunk's fix (F, NB, N, 3),
    sonar (S', NB, N, S), slip (ticks x sub-steps, NB, N, 4) normals and radio uniforms (U,);
    trace (ticks, B, N, 3) x 6, written when `record`.
    """
    dt_s, broadcast_every, fix_every, sonar_every, substeps = schedule
    reference_pose, reference_rate = reference
    pose, speed, angle, slip, link_bad, contacts, contacts_known = world
    (body, body_radius_m, counts_per_rad, fix_std, sonar, beams, centres, radii,
     obstacle_centres, obstacle_radii) = world_constants  # fmt: skip
    (k_consts, set_a, set_b, inputs, roles, peers, rules, scratch_ok, scratch_pose,
     origin) = controller  # fmt: skip
    (fix_pose, fix_valid, sonar_range, counts, ref_pose, ref_rate, peer_valid) = inputs
    peer_is_leader, peer_stopped, is_leader, slot_distance, slot_angle = roles
    peer_pose, peer_rate, peer_stamp_s = peers
    (per_robot, per_run, lead, metric_slot_distance, metric_slot_angle, metric_constants,
     previous, previous_known, errors, taken, sum_scratch) = metrics  # fmt: skip
    fix_draws, sonar_draws, slip_draws, uniforms = draws
    trace_true, trace_estimate, trace_desired, trace_errors, trace_delta_k, trace_kp = trace
    worlds, robots = pose.shape[0], pose.shape[1]
    noise_worlds = link_bad.shape[0]
    obstacles = obstacle_radii.shape[0]
    targets = radii.shape[0]
    beam_count = beams.shape[0]
    valid = np.ones(targets, dtype=np.bool_)
    rows = worlds * robots
    first_row = first_world * robots
    stop_row = stop_world * robots
    pose_rows = pose.reshape(rows, 3)
    speed_rows = speed.reshape(rows, 4)
    angle_rows = angle.reshape(rows, 4)
    slip_rows = slip.reshape(rows, 4)
    pose_out = np.empty((rows, 3))
    speed_out = np.empty((rows, 4))
    angle_out = np.empty((rows, 4))
    slip_out = np.empty((rows, 4))
    corrected = np.empty((robots, 2))
    positions = np.empty((robots, 2))
    robot_robot = np.empty((robots, robots), dtype=np.bool_)
    robot_obstacle = np.empty((robots, obstacles), dtype=np.bool_)
    sub_dt_s = dt_s / substeps
    fix_index = 0
    sonar_index = 0
    offset = 0
    for local in range(ticks):
        k = first_tick + local
        t_s = k * dt_s
        _deliver(t_s, radio, peers, robots, first_world, stop_world)

        # Sense: what the pins see at the start of the tick.
        fix_due = k % fix_every == 0
        sonar_due = k % sonar_every == 0
        for b in range(first_world, stop_world):
            nb = b if noise_worlds == worlds else 0
            if sonar_due:
                for i in range(robots):
                    centres[obstacles + i, 0] = pose[b, i, 0]
                    centres[obstacles + i, 1] = pose[b, i, 1]
            for i in range(robots):
                r = b * robots + i
                for w in range(4):
                    counts[r, w] = encoder_count(angle[b, i, w], counts_per_rad)
                fix_valid[r] = fix_due
                if fix_due:
                    for a in range(3):
                        fix_pose[r, a] = fix_axis(
                            pose[b, i, a], fix_draws[fix_index, nb, i, a], fix_std[a]
                        )
                if sonar_due:
                    valid[obstacles + i] = False
                    for s in range(beam_count):
                        sonar_range[r, s] = sonar_reading(
                            pose[b, i, 0], pose[b, i, 1], pose[b, i, 2] + beams[s], centres,
                            radii, valid, sonar_draws[sonar_index, nb, i, s], sonar,
                        )  # fmt: skip
                    valid[obstacles + i] = True
                for a in range(3):
                    ref_pose[r, a] = reference_pose[local, a]
                    ref_rate[r, a] = reference_rate[local, a]
                for j in range(robots):
                    peer_valid[r, j] = math.isfinite(peer_stamp_s[r, j])
        if fix_due:
            fix_index += 1
        if sonar_due:
            sonar_index += 1

        # Control: every robot, from one set of state arrays into the other.
        src, dst = (set_a, set_b) if k % 2 == 0 else (set_b, set_a)
        src_f, src_b = src
        out_f, out_b = dst
        state_f = (src_f[0], src_f[1], src_f[2], src_f[3], src_f[4], src_f[5], src_f[6], src_f[7])
        state_b = (src_b[0], src_b[1], src_b[2], src_b[3], src_b[4])
        inputs_f = (
            fix_pose, sonar_range, peer_pose, peer_rate, peer_stamp_s, ref_pose, ref_rate,
            slot_distance, slot_angle,
        )  # fmt: skip
        inputs_b = (counts, fix_valid, peer_valid, peer_is_leader, peer_stopped, is_leader)
        control_robots(
            first_row, stop_row, k_consts, t_s, sonar_due, state_f, state_b, inputs_f, inputs_b,
            rules, out_f, out_b, scratch_ok, scratch_pose, origin,
        )  # fmt: skip

        # Metrics of the sample at the start of the tick.
        accumulate_samples(
            first_world, stop_world, t_s, pose, reference_pose[local : local + 1], lead,
            metric_slot_distance, metric_slot_angle, obstacle_centres, obstacle_radii,
            metric_constants, contacts, contacts_known[0], previous, previous_known[0], per_robot,
            per_run, errors, taken, sum_scratch,
        )  # fmt: skip
        previous[first_world:stop_world] = taken[first_world:stop_world]
        previous_known[0] = True
        if record:
            for b in range(first_world, stop_world):
                for i in range(robots):
                    r = b * robots + i
                    for a in range(3):
                        trace_true[local, b, i, a] = pose[b, i, a]
                        trace_estimate[local, b, i, a] = out_f[0][r, a]
                        trace_desired[local, b, i, a] = out_f[10][r, a]
                        trace_errors[local, b, i, a] = errors[b, i, a]
                        trace_delta_k[local, b, i, a] = out_f[12][r, a]
                        trace_kp[local, b, i, a] = out_f[13][r, a]

        # World step: the due broadcasts meet the radio, then the bodies move and collide.
        offset = _broadcast(
            k, t_s, broadcast_every, pose, link_bad, link, uniforms, offset, radio,
            (out_f[0], out_f[1]), first_world, stop_world,
        )  # fmt: skip
        duty = out_f[9]
        for sub in range(substeps):
            noise = slip_draws[local * substeps + sub].reshape(noise_worlds * robots, 4)
            advance_bodies(
                first_row, stop_row, pose_rows, speed_rows, angle_rows, slip_rows, duty, noise,
                sub_dt_s, body, pose_out, speed_out, angle_out, slip_out,
            )  # fmt: skip
            pose_rows[first_row:stop_row] = pose_out[first_row:stop_row]
            speed_rows[first_row:stop_row] = speed_out[first_row:stop_row]
            angle_rows[first_row:stop_row] = angle_out[first_row:stop_row]
            slip_rows[first_row:stop_row] = slip_out[first_row:stop_row]
        for b in range(first_world, stop_world):
            for i in range(robots):
                positions[i, 0] = pose[b, i, 0]
                positions[i, 1] = pose[b, i, 1]
            push_apart(
                positions, body_radius_m, obstacle_centres, obstacle_radii, corrected,
                robot_robot, robot_obstacle,
            )  # fmt: skip
            for i in range(robots):
                pose[b, i, 0] = corrected[i, 0]
                pose[b, i, 1] = corrected[i, 1]
                for j in range(robots):
                    contacts[b, i, j] = robot_robot[i, j]
                for j in range(obstacles):
                    contacts[b, i, robots + j] = robot_obstacle[i, j]
        contacts_known[0] = True

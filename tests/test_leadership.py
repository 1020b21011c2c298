"""Leader election: every transition of the table in robot_firmware/leadership.py, failover
timing, split brain after a partition, the returning leader, and the slots."""

from __future__ import annotations

import math

import pytest

from robot_firmware.leadership import (
    Leadership,
    LeadershipParams,
    Phase,
    claim_beats,
    handover_offset,
    slot_of,
)

PARAMS = LeadershipParams(leader_timeout_s=0.5, listen_s=0.2, boot_patience_s=3.0)
PERIOD_S = 0.05  # broadcast period at 20 Hz
TICK_S = 0.01


def robot(index: int, boot_s: float = 0.0, count: int = 3, designated: int = 0) -> Leadership:
    return Leadership(index=index, count=count, designated_leader=designated, boot_s=boot_s,
                      params=PARAMS)  # fmt: skip


def following(machine: Leadership, leader: int | None, term: int) -> bool:
    return (machine.phase, machine.leader, machine.term) == (Phase.FOLLOWING, leader, term)


# -- boot ----------------------------------------------------------------------------------


def robot_led(index: int, boot_s: float = 0.0) -> Leadership:
    """A machine past its boot listening, with robot 0 leading term 0."""
    machine = robot(index, boot_s)
    if index == 0 and not machine.is_leader:
        machine.update(boot_s + PARAMS.listen_s)
    else:
        machine.hear(0, 0, True, boot_s + PARAMS.listen_s)
    return machine


def test_designated_leader_booting_at_the_runs_start_leads_term_0_at_once() -> None:
    leader = robot(0, boot_s=0.0)
    assert leader.is_leader and leader.term == 0 and leader.acting_leader(0.0) == 0


def test_designated_leader_listens_then_leads_term_0() -> None:
    leader = robot(0, boot_s=1.0)
    assert following(leader, None, 0)
    leader.hear(1, 0, False, 1.05)
    leader.update(1.19)
    assert not leader.is_leader
    leader.update(1.2)
    assert leader.is_leader and leader.term == 0 and leader.acting_leader(1.2) == 0


def test_followers_booting_expect_the_designated_leader() -> None:
    follower = robot(2, designated=1)
    assert following(follower, 1, 0)
    assert follower.acting_leader(0.1) == 1


def test_followers_give_a_leader_never_heard_the_boot_patience() -> None:
    follower = robot(1, boot_s=10.0)
    follower.update(12.9)
    assert following(follower, 0, 0)
    follower.update(13.01)
    assert follower.is_leader and follower.term == 1


def test_a_booting_leader_whose_process_is_up_is_waited_for_however_long_it_takes() -> None:
    # Containers start one by one: robot3 boots first, robot1's token appears, its first
    # frame comes much later than robot3's boot patience.
    follower = robot(2, boot_s=10.0)
    follower.set_alive(0, True, 10.5)
    follower.set_alive(1, True, 10.6)
    follower.update(20.0)
    assert following(follower, 0, 0)
    follower.hear(0, 0, True, 20.5)
    follower.update(20.6)
    assert following(follower, 0, 0) and follower.acting_leader(20.6) == 0
    # Once heard, a silence past the time-out is a loss again, token or not; robot2 (index 1)
    # is up, still unheard: robot3 waits for its claim instead of claiming itself.
    follower.update(21.2)
    assert follower.acting_leader(21.2) is None and not follower.is_leader
    follower.hear(1, 1, True, 21.3)
    assert following(follower, 1, 1)


def test_designated_leader_restarted_into_an_elected_swarm_follows() -> None:
    returning = robot(0, boot_s=40.0)
    returning.hear(2, 1, False, 40.05)
    returning.hear(1, 1, True, 40.1)
    returning.update(40.5)
    assert following(returning, 1, 1)


def test_designated_leader_hearing_only_a_later_term_never_claims_term_0() -> None:
    returning = robot(0, boot_s=40.0)
    returning.hear(2, 1, False, 40.05)
    returning.update(40.3)
    assert following(returning, None, 1)


def test_designated_leader_restarted_before_any_election_leads_term_0_again() -> None:
    returning = robot(0, boot_s=25.2)
    returning.hear(1, 0, False, 25.25)
    returning.update(25.45)
    assert returning.is_leader and returning.term == 0


def test_resumed_designated_leader_listens_again_before_it_claims() -> None:
    leader = robot_led(0)
    leader.update(4.0)
    leader.resume(5.0)
    leader.update(5.1)
    assert not leader.is_leader
    leader.hear(1, 1, True, 5.15)
    leader.update(5.3)
    assert following(leader, 1, 1)


def test_index_outside_the_swarm_is_refused() -> None:
    with pytest.raises(ValueError, match="index 3"):
        robot(3)


# -- claims --------------------------------------------------------------------------------


def test_claim_order_is_higher_term_then_lower_index() -> None:
    assert claim_beats(2, 2, 1, 0)
    assert claim_beats(1, 0, 1, 1)
    assert not claim_beats(1, 1, 1, 0)
    assert not claim_beats(0, 0, 1, 2)
    assert not claim_beats(1, 1, 1, 1)


def test_follower_adopts_a_claim_with_a_higher_term() -> None:
    follower = robot(2)
    follower.hear(1, 1, True, 5.0)
    assert following(follower, 1, 1)


def test_follower_ignores_a_claim_with_a_lower_term() -> None:
    follower = robot(2)
    follower.hear(1, 3, True, 5.0)
    follower.hear(0, 2, True, 5.01)
    assert following(follower, 1, 3)


def test_follower_takes_the_lower_index_on_a_tie() -> None:
    follower = robot(2)
    follower.hear(1, 1, True, 5.0)
    follower.hear(0, 1, True, 5.01)
    assert following(follower, 0, 1)
    follower.hear(1, 1, True, 5.02)
    assert following(follower, 0, 1)


def test_leaders_claim_in_its_term_keeps_it_alive() -> None:
    follower = robot(2)
    t_s = 0.0
    while t_s < 3.0:
        follower.hear(0, 0, True, t_s)
        follower.update(t_s + TICK_S)
        t_s += PERIOD_S
    assert following(follower, 0, 0)
    assert follower.acting_leader(t_s) == 0


def test_leader_frame_without_a_claim_means_it_stepped_down() -> None:
    follower = robot(2)
    follower.hear(0, 0, False, 0.2)
    assert following(follower, None, 0)


def test_frame_with_a_later_term_and_no_claim_drops_the_known_leader() -> None:
    follower = robot(2)
    follower.hear(1, 4, False, 2.0)
    assert following(follower, None, 4)
    follower.hear(1, 4, True, 2.05)
    assert following(follower, 1, 4)


def test_leader_steps_down_on_a_better_claim() -> None:
    leader = robot_led(0)
    leader.hear(2, 3, True, 10.1)
    assert following(leader, 2, 3)


def test_leader_keeps_the_lead_against_a_weaker_claim() -> None:
    leader = robot_led(0)
    leader.hear(1, 0, True, 0.5)
    leader.hear(2, 0, True, 0.5)
    assert leader.is_leader and leader.term == 0


def test_leader_steps_down_on_a_later_term_without_a_claim() -> None:
    leader = robot_led(0)
    leader.hear(2, 2, False, 1.0)
    assert following(leader, None, 2)


def test_own_and_unknown_senders_are_ignored() -> None:
    follower = robot(1)
    follower.hear(1, 9, True, 0.1)
    follower.hear(7, 9, True, 0.1)
    follower.set_alive(7, False, 0.1)
    assert following(follower, 0, 0)


def test_resume_after_a_short_gap_changes_nothing() -> None:
    leader = robot_led(0)
    leader.update(2.0)
    leader.resume(2.4)
    assert leader.is_leader and leader.term == 0


def test_resume_after_time_went_back_forgets_the_leader() -> None:
    follower = robot_led(2)
    follower.update(2.0)
    follower.resume(1.5)
    assert following(follower, None, 0)


def test_new_epoch_forgets_when_peers_were_heard() -> None:
    follower = robot_led(2)
    follower.hear(1, 0, False, 30.0)
    follower.update(30.0)
    follower.new_epoch(29.0)  # a world resumed from a checkpoint a second back
    assert following(follower, None, 0)
    assert not follower.is_live(1, 29.0)


def test_resume_forgets_the_leader_but_keeps_the_term() -> None:
    leader = robot_led(0)
    leader.hear(1, 0, False, 0.0)
    leader.resume(3.0)
    assert following(leader, None, 0)


# -- failover ------------------------------------------------------------------------------


def run_swarm(
    machines: dict[int, Leadership],
    start_s: float,
    end_s: float,
    links: set[frozenset[int]] | None = None,
) -> list[tuple[float, int, int]]:
    """Broadcast every period between live machines; returns (t, leader, term) of every
    leader frame sent."""
    claims = []
    t_s = start_s
    step = 0
    while t_s < end_s:
        for m in machines.values():
            m.update(t_s)
        if step % round(PERIOD_S / TICK_S) == 0:
            for sender, m in machines.items():
                if m.is_leader:
                    claims.append((t_s, sender, m.term))
                for receiver, other in machines.items():
                    if receiver != sender and (links is None or {sender, receiver} in links):
                        other.hear(sender, m.term, m.is_leader, t_s)
        step += 1
        t_s = start_s + step * TICK_S
    return claims


def test_lowest_live_follower_takes_over_within_a_second_of_a_silent_leader() -> None:
    swarm = {i: robot(i) for i in range(3)}
    run_swarm(swarm, 0.0, 25.0)
    kill_s = 25.0
    del swarm[0]
    claims = run_swarm(swarm, kill_s, 30.0)
    first_s, first_leader, first_term = claims[0]
    print(f"\nfirst claim of the new leader {first_s - kill_s:.3f} s after the kill")
    assert first_leader == 1 and first_term == 1
    assert first_s - kill_s <= 1.0
    assert {(leader, term) for _, leader, term in claims} == {(1, 1)}
    assert following(swarm[2], 1, 1)


def test_token_gone_takes_over_at_once() -> None:
    swarm = {i: robot(i) for i in range(3)}
    run_swarm(swarm, 0.0, 2.0)
    del swarm[0]
    for m in swarm.values():
        m.set_alive(0, False, 2.0)
    swarm[1].update(2.0)
    assert swarm[1].is_leader and swarm[1].term == 1


def test_token_back_without_a_claim_elects_nobody_new() -> None:
    follower = robot(2)
    follower.hear(1, 0, False, 0.1)
    follower.set_alive(0, False, 0.2)
    follower.set_alive(0, True, 0.3)
    follower.hear(0, 0, True, 0.35)
    follower.update(0.36)
    assert following(follower, 0, 0)


def test_follower_waits_for_a_live_lower_index_then_takes_over_if_it_dies_too() -> None:
    follower = robot(2, boot_s=10.0)
    follower.hear(1, 0, False, 12.8)
    follower.update(13.1)  # leader 0 never heard, 1 is live and lower: wait
    assert following(follower, None, 0)
    follower.update(13.4)  # 1 silent as well now
    assert follower.is_leader and follower.term == 1


def test_returning_old_leader_boots_as_a_follower_and_adopts_the_term() -> None:
    swarm = {i: robot(i) for i in range(3)}
    run_swarm(swarm, 0.0, 25.0)
    del swarm[0]
    run_swarm(swarm, 25.0, 40.0)
    swarm[0] = robot(0, boot_s=40.0)
    claims = run_swarm(swarm, 40.0, 60.0)
    assert {(leader, term) for _, leader, term in claims} == {(1, 1)}
    assert following(swarm[0], 1, 1)
    assert following(swarm[2], 1, 1)


def test_no_two_leaders_claim_the_same_instant_through_kill_and_restart() -> None:
    swarm = {i: robot(i) for i in range(3)}
    claims = run_swarm(swarm, 0.0, 25.0)
    del swarm[0]
    claims += run_swarm(swarm, 25.0, 40.0)
    swarm[0] = robot(0, boot_s=40.0)
    claims += run_swarm(swarm, 40.0, 60.0)
    per_instant: dict[float, set[int]] = {}
    for t_s, leader, _ in claims:
        per_instant.setdefault(round(t_s, 6), set()).add(leader)
    assert all(len(leaders) == 1 for leaders in per_instant.values())
    terms = [term for _, _, term in claims]
    assert terms == sorted(terms)


def test_partitioned_robot_that_elected_itself_steps_down_when_it_hears_a_higher_term() -> None:
    swarm = {i: robot(i) for i in range(3)}
    run_swarm(swarm, 0.0, 5.0)
    # robot 2 is cut off from the rest; the other two keep their leader.
    isolated = {frozenset({0, 1})}
    run_swarm(swarm, 5.0, 7.0, links=isolated)
    assert swarm[2].is_leader and swarm[2].term == 1
    assert swarm[0].is_leader and swarm[0].term == 0
    # The leader dies and nobody hears anybody: robot 1 elects itself in term 1 as well. On
    # healing, the tie in term 1 goes to the lower index: robot 2 steps down.
    del swarm[0]
    run_swarm(swarm, 7.0, 9.0, links=set())
    assert swarm[1].is_leader and swarm[1].term == 1
    claims = run_swarm(swarm, 9.0, 10.0)  # healed
    assert following(swarm[2], 1, 1)
    assert swarm[1].is_leader
    late = [(leader, term) for t_s, leader, term in claims if t_s >= 9.0 + PERIOD_S]
    assert set(late) == {(1, 1)}


def test_isolated_leader_steps_down_for_the_majoritys_higher_term() -> None:
    swarm = {i: robot(i) for i in range(3)}
    run_swarm(swarm, 0.0, 5.0)
    run_swarm(swarm, 5.0, 8.0, links={frozenset({1, 2})})  # robot 0 alone
    assert swarm[0].is_leader and swarm[0].term == 0
    assert swarm[1].is_leader and swarm[1].term == 1
    claims = run_swarm(swarm, 8.0, 9.0)
    assert following(swarm[0], 1, 1)
    assert following(swarm[2], 1, 1)
    assert {(leader, term) for t_s, leader, term in claims if t_s > 8.0} == {(1, 1)}


def test_liveness_follows_frames_and_tokens() -> None:
    follower = robot(2)
    assert follower.is_live(2, 100.0)
    assert not follower.is_live(1, 0.0)
    follower.hear(1, 0, False, 1.0)
    assert follower.is_live(1, 1.5)
    assert not follower.is_live(1, 1.51)
    follower.set_alive(1, False, 1.1)
    assert not follower.is_live(1, 1.2)


def test_changes_are_recorded_with_time_and_term() -> None:
    follower = robot(2)
    follower.hear(1, 1, True, 5.0)
    assert [(c.t_s, c.term, c.leader) for c in follower.changes] == [(5.0, 1, 1)]


# -- slots -----------------------------------------------------------------------------------


SLOTS = [(0.0, 0.0), (0.8, math.radians(150)), (0.8, math.radians(-150))]


def test_followers_keep_their_slots_relative_to_any_leader() -> None:
    assert slot_of(2, 0, 0, SLOTS) == SLOTS[2]
    assert slot_of(2, 1, 0, SLOTS) == SLOTS[2]
    assert slot_of(1, 0, 0, SLOTS) == SLOTS[1]


def test_returning_designated_leader_takes_the_vacated_slot() -> None:
    assert slot_of(0, 1, 0, SLOTS) == SLOTS[1]
    assert slot_of(0, 2, 0, SLOTS) == SLOTS[2]
    assert slot_of(0, None, 0, SLOTS) == (0.0, 0.0)


# -- handover ------------------------------------------------------------------------------


def test_handover_offset_starts_at_the_new_leader_and_shrinks_at_its_speed() -> None:
    offset, rate = handover_offset((0.3, -0.4), 0.0, 0.1)
    assert offset == pytest.approx((0.3, -0.4)) and rate == pytest.approx((-0.06, 0.08))
    offset, rate = handover_offset((0.3, -0.4), 2.0, 0.1)
    assert math.hypot(*offset) == pytest.approx(0.3)
    assert handover_offset((0.3, -0.4), 5.0, 0.1) == ((0.0, 0.0), (0.0, 0.0))
    assert handover_offset((0.0, 0.0), 1.0, 0.1) == ((0.0, 0.0), (0.0, 0.0))

"""Who leads the formation: leader terms, failover and slots (DESIGN.md §7, §7.1 "Leader term").

The paper's swarm has one fixed leader (§5); a swarm that loses it stops.  Here leadership is
a term (epoch) number carried in every authenticated radio frame (robot_firmware/net/frames.py,
field `term`) and a role bit: a frame with role leader claims to lead in its term.  This module
is the rule, as a pure state machine: no zenoh, no clock (time is `t_s`, simulation seconds, an
argument), so every transition is tested without a network (tests/test_leadership.py).

Every robot knows its own index and the robots' names (so their count) from the scenario, and
which robot the scenario names leader (the *designated* leader).  From the frames it accepts it
keeps, per peer, when it last heard the peer, the peer's term and whether the peer claims to
lead; the robot runtime may add that a peer's liveliness token is gone (or back).

**Order of claims.**  A claim (term T, sender s) beats (T', s') when T > T', or T == T' and
s < s' (the lower index wins a tie).  A robot always follows the best claim it has heard.

**Live.**  A peer is live while it was heard within `leader_timeout_s` and its liveliness token
is not known to be gone, or while its token is there and it has not been heard at all yet (up
and still booting).  The robot itself is always live.

**Lockstep: frames only.**  A token comes and goes at a wall-clock instant, which falls on a
different tick of a lockstep run each time it is replayed.  So in lockstep (`use_tokens` off,
set by the firmware from the world's clock mode) tokens are recorded but do not count: a peer
is live while heard within `leader_timeout_s` of simulation time, and a leader is lost once
unheard for that long.  Then who leads, and when it changes, follows from the frames the world
delivers and their simulation times alone, and a campaign that kills the leader replays.

**Leader lost.**  The leader a robot follows is lost when its token is gone, or when no claim of
it was heard for `leader_timeout_s` (counted from when the robot started waiting for it: the
term's adoption or the leader's last claim; a leader not heard since this robot booted gets
`boot_patience_s`, since the robots of a swarm do not boot at the same instant), but never
while its token is there and it has not been heard at all yet: its process is up and still
booting, as when containers start one by one.  While the leader is lost, the live robot with
the lowest index (the lost leader excluded) raises the term to one above the highest it has
seen and leads, unless it is alone (below); the others wait for its claim.  If that candidate
dies too, it stops being live after the same time-out and the next one takes over.  So a claim
follows a death within `leader_timeout_s` plus one broadcast period (0.5 s + 50 ms at the
defaults), or at the next tick when the runtime reports the token gone.

**Not alone.**  A robot that hears no other live robot cannot tell being cut off (a radio
partition) from being the last one left, so it does not take over: it waits without a leader,
and without a leader a follower holds still (inactive), a stopped body where the others last
heard it.  When the partition heals it hears the leader's claim and follows it again, and the
formation is as before.  In real time a robot whose every peer's token is gone is the last one
left and does take over; in lockstep (frames only) it waits.

**Back from a gap.**  A robot that was not updated for `update_gap_s` (frozen, safe-stopped,
its clock jumped) heard nothing meanwhile, so a peer's silence counts only from its next update
(`listening_since_s`); and since its own link to the router may have lapsed too (every peer's
token then goes and comes back as it reconnects), tokens count again only after it has listened
for `leader_timeout_s`.  So a robot continued after SIGSTOP never takes the silence it slept
through for a lost leader.  Its simulation time does not always show the gap, though: it may
first read a backlog of messages queued before the router dropped its session, with times
one period apart, while the reconnection takes the tokens away.  So the runtime also watches
its own loop, and for a while after the loop stalled the tokens do not count at all
(`use_tokens` off, robot_firmware/tick_scheduler.py `LoopStallWatch`).

Transitions (`LEADING` / `FOLLOWING(L)`, with L None while no leader is known):

| state           | event                                            | next            | term    |
|-----------------|--------------------------------------------------|-----------------|---------|
| boot at t = 0   | designated leader (the run's start)              | LEADING         | 0       |
| boot            | designated leader, later                         | FOLLOWING(None) | 0       |
| boot            | any other robot                                  | FOLLOWING(d)    | 0       |
| FOLLOWING(None) | `update`: designated leader, `listen_s` after    | LEADING         | 0       |
|                 | boot, still term 0 and no claim heard            |                 |         |
| FOLLOWING(L)    | claim (T, s) that beats (term, L), or L None and | FOLLOWING(s)    | T       |
|                 | T >= term                                        |                 |         |
| FOLLOWING(L)    | claim of L in the current term                   | FOLLOWING(L)    | same    |
| FOLLOWING(L)    | frame of L without a claim, current term         | FOLLOWING(None) | same    |
| FOLLOWING/LEAD. | any frame with a term above ours, no claim       | FOLLOWING(None) | T       |
| FOLLOWING(L)    | `update`: L lost, this robot lowest live index,  | LEADING         | max + 1 |
|                 | not alone                                        |                 |         |
| FOLLOWING(L)    | `update`: L lost, a lower index is live, or      | FOLLOWING(None) | same    |
|                 | this robot alone                                 |                 |         |
| LEADING         | claim (T, s) that beats (term, self)             | FOLLOWING(s)    | T       |
| LEADING         | claim that does not beat ours                    | LEADING         | same    |
| any             | `resume` after a gap up to `leader_timeout_s`    | unchanged       | same    |
| any             | `resume` after a longer gap, or time went back:  | FOLLOWING(None) | same    |
|                 | listens again as at boot                         |                 |         |
| any             | `new_epoch` (the world's clock jumped): peers    | FOLLOWING(None) | same    |
|                 | unheard, then as `resume`                        |                 |         |

d: the designated leader, expected in term 0.  A boot at simulation time 0 is the run's start,
where nobody can have been elected: there the designated leader leads term 0 at once, as the
paper's fixed leader does (and as the batch simulator's does).  Any other boot is in term 0 as a
follower.  The designated leader listens for `listen_s` (4 broadcast periods) before it claims
term 0: in a swarm starting up it hears nothing better and leads; restarted into a running swarm
that elected another leader, it hears that leader's claim or a later term in the peers' frames,
follows, and takes the vacated slot (below).  Once a term above 0 was seen it never claims term 0
again.

No split brain: a robot alone never elects itself (above), and a leader partitioned from the
rest (which the others replaced, or one of two groups that each elected) keeps its term only
until it hears a claim that beats it (a higher term, or the same term from a lower index); then
it follows, so two leaders never both act once they hear each other.

**Handover.**  A new leader starts from where it is: its reference is the trajectory plus an
offset that shrinks at `handover_speed_mps` (`handover_offset`), so it does not rush at the
trajectory point, where the dead leader's body stopped.

**Rejoin.**  A follower that starts following a leader after the run's start (booted into a
running swarm, resumed after a freeze, or re-referenced to a new leader) is seldom near its slot,
and the control law's pull on a far reference overpowers the avoidance.  So its slot starts where
it is, relative to the leader, and swings round to the real one at `rejoin_speed_mps`
(`rejoin_slot`): distance and angle move together, the angle the shorter way round, so the path
goes round the leader instead of across it.  At the run's start (simulation time 0) every robot
drives straight to its slot, as in the paper.

**Slots.**  The scenario's slots are relative to the leader (eq. 17).  With robot L leading, a
follower that has a scenario slot keeps it, relative to L; the designated leader, which has no
slot of its own, takes L's slot (the slot L vacated).  So with robot2 leading, robot3 keeps its
slot behind robot2 and a returning robot1 takes robot2's old slot; with the designated leader
leading again every robot is back in its scenario slot (`slot_of`).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat


class LeadershipParams(BaseModel):
    """Constants of the election rule."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    leader_timeout_s: PositiveFloat = 0.5
    """A leader unheard for this long is lost: 10 broadcast periods at 20 Hz."""
    handover_speed_mps: PositiveFloat = 0.15
    """How fast a new leader's reference closes in on the trajectory (`handover_offset`)."""
    rejoin_speed_mps: PositiveFloat = 0.45
    """How fast a rejoining follower's slot moves to its real one (`rejoin_slot`), relative to
    the leader: with the leader at 0.525 m/s the robot stays within its 0.9 m/s."""
    stopped_coast_s: float = Field(default=0.2, ge=0.0)
    """How long a silent peer is taken to have moved on at its last broadcast velocity before
    it stopped (the firmware holds it there): its last frame's age (up to a broadcast period,
    50 ms), the world's act time-out before it brakes the body (100 ms) and the motors' time
    constant (50 ms)."""
    listen_s: PositiveFloat = 0.2
    """How long the designated leader listens after booting before it claims term 0."""
    update_gap_s: PositiveFloat = 0.1
    """A gap this long between the robot's own updates (it was frozen, safe-stopped, or its
    clock jumped) means it heard nothing meanwhile: silence counts again from its next update
    (`Leadership.listening_since_s`)."""
    boot_patience_s: PositiveFloat = 3.0
    """How long a booting robot waits for the first claim of the leader it expects."""


class Phase(enum.Enum):
    LEADING = "leading"
    FOLLOWING = "following"


@dataclass(slots=True)
class PeerRecord:
    """What one robot knows of a peer from its accepted frames and its liveliness token."""

    last_heard_s: float = -math.inf
    term: int = 0
    claims_lead: bool = False
    token_gone: bool = False
    token_seen: bool = False
    """The runtime has seen the peer's liveliness token (the process is up)."""


@dataclass(frozen=True, slots=True)
class LeaderChange:
    """A change of who this robot follows or whether it leads (for logs and telemetry)."""

    t_s: float
    term: int
    leader: int | None
    reason: str


def claim_beats(term: int, sender: int, other_term: int, other_sender: int) -> bool:
    """Whether a claim to lead (term, sender) beats (other_term, other_sender)."""
    return term > other_term or (term == other_term and sender < other_sender)


@dataclass
class Leadership:
    """One robot's view of who leads (the table in the module docstring)."""

    index: int
    count: int
    designated_leader: int
    boot_s: float
    params: LeadershipParams = field(default_factory=LeadershipParams)
    term: int = field(init=False, default=0)
    phase: Phase = field(init=False, default=Phase.FOLLOWING)
    leader: int | None = field(init=False, default=None)
    waiting_since_s: float = field(init=False)
    """Since when the current leader has not been heard (boot, adoption or its last claim)."""
    highest_term_seen: int = field(init=False, default=0)
    claim_heard: bool = field(init=False, default=False)
    """Whether any peer's claim to lead was heard since boot (or the last `resume`)."""
    last_update_s: float = field(init=False, default=-math.inf)
    listening_since_s: float = field(init=False)
    """Since when this robot has been updated without a gap (boot, or its last gap): a peer's
    silence before then is no evidence that the peer is gone."""
    listen_from_s: float = field(init=False, default=0.0)
    """Boot (or the last `resume`): the designated leader listens `listen_s` from here."""
    peers: list[PeerRecord] = field(init=False)
    changes: list[LeaderChange] = field(init=False, default_factory=list)
    use_tokens: bool = field(init=False, default=True)
    """Whether the peers' liveliness tokens count (`set_alive`).  Off in lockstep: a token
    comes and goes at a wall-clock instant, so only frames and their simulation times decide
    who is live, and a run replays."""

    def __post_init__(self) -> None:
        if not 0 <= self.index < self.count or not 0 <= self.designated_leader < self.count:
            raise ValueError(
                f"index {self.index} and designated leader {self.designated_leader} must be "
                f"in 0..{self.count - 1}"
            )
        self.peers = [PeerRecord() for _ in range(self.count)]
        p = self.params
        self.waiting_since_s = self.boot_s + max(p.boot_patience_s - p.leader_timeout_s, 0.0)
        self.claim_heard = False
        self.listen_from_s = self.boot_s
        self.listening_since_s = self.boot_s
        if self.index != self.designated_leader:
            self.leader = self.designated_leader
        elif self.boot_s <= 0.0:
            self._set(Phase.LEADING, self.index, 0, self.boot_s, "designated leader at t = 0")

    @property
    def is_leader(self) -> bool:
        return self.phase is Phase.LEADING

    # -- inputs --------------------------------------------------------------------------

    def hear(self, sender: int, term: int, claims_lead: bool, t_s: float) -> None:
        """An accepted frame of `sender` (its term and role) at simulation time `t_s`."""
        if sender == self.index or not 0 <= sender < self.count:
            return
        peer = self.peers[sender]
        peer.last_heard_s = max(peer.last_heard_s, t_s)
        peer.term = term
        peer.claims_lead = claims_lead
        self.highest_term_seen = max(self.highest_term_seen, term)
        if claims_lead:
            self.claim_heard = True
            self._hear_claim(sender, term, t_s)
        elif term > self.term:
            self._set(Phase.FOLLOWING, None, term, t_s, f"robot {sender} is in a later term")
        elif sender == self.leader and term == self.term and not self.is_leader:
            self._set(Phase.FOLLOWING, None, term, t_s, f"robot {sender} stepped down")

    def set_alive(self, peer: int, alive: bool, t_s: float) -> None:
        """The runtime saw `peer`'s liveliness token appear (alive) or go away."""
        if peer == self.index or not 0 <= peer < self.count:
            return
        self.peers[peer].token_gone = not alive
        self.peers[peer].token_seen = self.peers[peer].token_seen or alive

    def resume(self, t_s: float) -> None:
        """After a gap in the sense messages (a frozen process, a world restart).

        A gap no longer than `leader_timeout_s` since the last `update` changes nothing: no
        peer can have found this robot's claims missing.  After a longer gap, or when time went
        back, it does not act on who led before: it follows whoever claims next, keeping the
        term, and the designated leader listens again before it claims term 0."""
        gap_s = t_s - self.last_update_s
        if not 0.0 <= gap_s <= self.params.update_gap_s:
            self.listening_since_s = t_s
        if 0.0 <= gap_s <= self.params.leader_timeout_s:
            return
        self.claim_heard = False
        self.listen_from_s = t_s
        self._set(Phase.FOLLOWING, None, self.term, t_s, "resumed after a gap")

    def new_epoch(self, t_s: float) -> None:
        """The world's clock jumped (a restarted world): every time heard before is void, so
        no peer is live until heard again; then as `resume` after a long gap."""
        for peer in self.peers:
            peer.last_heard_s = -math.inf
        self.last_update_s = -math.inf
        self.resume(t_s)

    def update(self, t_s: float) -> None:
        """Run the time-outs at `t_s`: detect a lost leader and elect (once per tick)."""
        gap_s = t_s - self.last_update_s
        if self.last_update_s > -math.inf and not 0.0 <= gap_s <= self.params.update_gap_s:
            self.listening_since_s = t_s  # deaf meanwhile: the silence proves nothing
        self.last_update_s = t_s
        if self.is_leader:
            return
        if self._designated_claim_due(t_s):
            self._set(Phase.LEADING, self.index, 0, t_s, "designated leader, term 0 unclaimed")
            return
        if not self._leader_lost(t_s):
            return
        live = [i for i in range(self.count) if i != self.leader and self.is_live(i, t_s)]
        if min(live) == self.index and self._has_company(live, t_s):
            term = max(self.term, self.highest_term_seen) + 1
            self._set(Phase.LEADING, self.index, term, t_s, "leader lost: lowest live index")
        elif self.leader is not None:
            self._set(Phase.FOLLOWING, None, self.term, self.waiting_since_s, "leader lost")

    # -- queries -------------------------------------------------------------------------

    def is_live(self, robot: int, t_s: float) -> bool:
        """Whether `robot` counts as live at `t_s` (itself always)."""
        if robot == self.index:
            return True
        return self._peer_live(self.peers[robot], self._tokens_count(t_s), t_s)

    def live_flags(self, t_s: float) -> list[bool]:
        """`is_live` of every robot at `t_s`, by index, in one pass (the firmware asks each
        tick for every peer)."""
        tokens = self._tokens_count(t_s)
        live = self._peer_live
        flags = [live(peer, tokens, t_s) for peer in self.peers]
        flags[self.index] = True
        return flags

    def _peer_live(self, peer: PeerRecord, tokens: bool, t_s: float) -> bool:
        if tokens and peer.token_gone:
            return False
        if peer.last_heard_s == -math.inf:
            return tokens and peer.token_seen  # up and still booting: it will speak
        heard_s = max(peer.last_heard_s, self.listening_since_s)
        return t_s - heard_s <= self.params.leader_timeout_s

    def acting_leader(self, t_s: float) -> int | None:
        """The robot whose trajectory the formation follows at `t_s`, or None (none known, or
        the one followed is lost)."""
        if self.is_leader:
            return self.index
        if self.leader is None or self._leader_lost(t_s):
            return None
        return self.leader

    # -- internals -----------------------------------------------------------------------

    def _designated_claim_due(self, t_s: float) -> bool:
        return (
            self.index == self.designated_leader
            and self.term == 0
            and self.highest_term_seen == 0
            and self.leader is None
            and not self.claim_heard
            and t_s >= self.listen_from_s + self.params.listen_s
        )

    def _has_company(self, live: list[int], t_s: float) -> bool:
        """Whether this robot may take over: another robot is live, or (tokens counting) every
        other robot's token is gone, so it is the last one left.  Alone otherwise, it cannot
        tell being cut off from being the last, and does not lead."""
        if len(live) > 1:
            return True
        others = [peer for i, peer in enumerate(self.peers) if i != self.index]
        return self._tokens_count(t_s) and all(peer.token_gone for peer in others)

    def _tokens_count(self, t_s: float) -> bool:
        """Tokens count in real time once this robot has listened for `leader_timeout_s`
        without a gap: back from one (a freeze), its own link to the router may have lapsed,
        and every peer's token then goes and comes back as it reconnects."""
        return self.use_tokens and t_s - self.listening_since_s >= self.params.leader_timeout_s

    def _leader_lost(self, t_s: float) -> bool:
        if self.leader is not None and self._tokens_count(t_s):
            peer = self.peers[self.leader]
            if peer.token_gone:
                return True
            if peer.token_seen and peer.last_heard_s == -math.inf:
                return False  # its process is up and has not spoken yet: still booting
        waited_s = t_s - max(self.waiting_since_s, self.listening_since_s)
        return waited_s > self.params.leader_timeout_s

    def _hear_claim(self, sender: int, term: int, t_s: float) -> None:
        if sender == self.leader and term == self.term:
            self.waiting_since_s = max(self.waiting_since_s, t_s)
            return
        current = self.index if self.is_leader else self.leader
        if current is None:
            if term >= self.term:
                self._set(Phase.FOLLOWING, sender, term, t_s, f"robot {sender} claims the lead")
            return
        if claim_beats(term, sender, self.term, current):
            self._set(Phase.FOLLOWING, sender, term, t_s, f"robot {sender} has the better claim")

    def _set(self, phase: Phase, leader: int | None, term: int, t_s: float, reason: str) -> None:
        changed = (phase, leader, term) != (self.phase, self.leader, self.term)
        self.phase, self.leader, self.term = phase, leader, term
        self.waiting_since_s = t_s
        if changed:
            self.changes.append(LeaderChange(t_s=t_s, term=term, leader=leader, reason=reason))


def handover_offset(
    offset0_m: tuple[float, float], elapsed_s: float, speed_mps: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """A new leader's reference offset from the trajectory (bumpless transfer), and its rate.

    At the handover the offset is the new leader's position minus the trajectory point, so its
    reference starts where it is; the offset then shrinks along its first direction at
    `speed_mps` until it is gone.  Without it the new leader would jump at the trajectory point,
    which is where the dead leader's body stopped."""
    length_m = math.hypot(*offset0_m)
    left_m = length_m - speed_mps * max(elapsed_s, 0.0)
    if length_m == 0.0 or left_m <= 0.0:
        return (0.0, 0.0), (0.0, 0.0)
    ux, uy = offset0_m[0] / length_m, offset0_m[1] / length_m
    return (ux * left_m, uy * left_m), (-ux * speed_mps, -uy * speed_mps)


def rejoin_slot(
    start: tuple[float, float], slot: tuple[float, float], elapsed_s: float, speed_mps: float
) -> tuple[float, float]:
    """A rejoining follower's slot (distance_m, angle_rad) relative to the leader (eq. 17),
    `elapsed_s` after it started at `start` (where the robot was), on its way to `slot`.

    Distance and angle move together in proportion, the angle the shorter way round, over
    the path's length (radial change and arc at the mean distance) at `speed_mps`: the slot
    swings round the leader instead of cutting across it, and never comes closer to the
    leader than the nearer of the two distances."""
    (d0, a0), (d1, a1) = start, slot
    turn = math.remainder(a1 - a0, math.tau)
    length_m = math.hypot(d1 - d0, 0.5 * (d0 + d1) * turn)
    done = 1.0 if length_m == 0.0 else min(1.0, speed_mps * max(elapsed_s, 0.0) / length_m)
    if done >= 1.0:
        return slot
    return d0 + done * (d1 - d0), a0 + done * turn


def slot_of(
    robot: int,
    leader: int | None,
    designated_leader: int,
    slots: Sequence[tuple[float, float]],
) -> tuple[float, float]:
    """The (distance_m, angle_rad) slot of `robot` relative to `leader` (eq. 17).

    `slots[i]` is robot i's scenario slot (the designated leader's entry is unused). A robot
    with a scenario slot keeps it; the designated leader takes the slot of whoever leads (the
    one that leader vacated). With no leader known, the designated leader takes no slot yet
    ((0, 0); it is inactive until it hears a leader anyway).
    """
    if robot != designated_leader:
        return slots[robot]
    if leader is None or leader == designated_leader:
        return (0.0, 0.0)
    return slots[leader]

"""The host's hold on the board and the phone, on the control tick: what the board client's events mean
for the run (``events.jsonl`` records, the fault journal), the host's view of the board by the age of its
telemetry, re-arming through the protocol, and the operator's own arm and disarm (the ground station).

Re-arming: after a FAILSAFE (the board's link watchdog), a reset or a reconnect the host arms the board
again — only through the protocol: an acknowledged ``Arm`` in a session whose handshake is done
(:attr:`BoardClient.connected`), retried on the next tick when refused. A board the operator disarmed is
never re-armed on the host's own account: the Disarm cancels a re-arm already pending (one already sent is
overtaken by the Disarm, which the board carries out after it), and the host waits for the operator's Arm.

What the rest of the host is told (:meth:`BoardWatch.take_upsets`): that the board has left the state the
host commanded, or may have (``failsafe``, ``reset``, ``link_lost``, ``reconnect``, ``disarmed``: the
board DISARMED by no command the host still means, an operator's Disarm retried after the Arm that
followed it) — the host re-enters its warm-up before it steers again (:mod:`hil.runtime.host`). Telemetry
that merely goes stale is not one: the host holds while it cannot see the board and carries on if the
board comes back armed in the same session.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from hil.link.board import BoardClient
from hil.link.board.events import (
    BoardResetEvent,
    ConnectedEvent,
    LinkLostEvent,
    LogEvent,
    SilenceEvent,
    StateEvent,
)
from hil.link.throttle import Throttle
from hil.runtime.faults import BoardLink, FaultJournal
from hil.runtime.runlog import EventLog
from protocol.errors import CommandFailed
from protocol.messages import Arm, BoardState, Disarm, Telemetry
from protocol.reliable import Command

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class View:
    """The host's view of the board at one tick: ``link``; ``telemetry`` (None unless live); ``age_s`` of
    the latest telemetry received (None: none yet); ``made_s``, the host time (s) ``telemetry`` was made
    (None unless live) — the one pair, never the client's newer time beside an older message."""

    link: BoardLink
    telemetry: Telemetry | None
    age_s: float | None
    made_s: float | None = None


STATE_CONFIRM_S = 0.5
"""How long after the board settled an Arm or a Disarm (acknowledged it, or the Disarm failed) its telemetry
may still show the state before: a few telemetry periods for the new state to reach the host. Past it, a
board the operator holds disarmed that says ARMED has not carried the Disarm out, and a board that
acknowledged the host's Arm and says DISARMED has not carried the Arm out."""

BOARD_LOGS_RECORDED_PER_S = 20
"""The board's ``Log`` frames written to ``events.jsonl`` per second of host time (a board logs a few a
second: its state changes, faults, refused commands); beyond, counted."""


class BoardWatch:
    """See the module docstring. ``stale_after_s``: telemetry older than this is not live."""

    def __init__(
        self, client: BoardClient, events: EventLog, journal: FaultJournal, stale_after_s: float
    ) -> None:
        self.client = client
        self.events = events
        self.journal = journal
        self.stale_after_s = stale_after_s
        self.failsafes = self.resets = self.link_losses = self.reconnects = self.rearms = 0
        self.stale_episodes = 0
        self.host_stalls = 0  # control ticks that ran more than stale_after_s after their deadline
        self.unasked_disarms = 0  # ARMED → DISARMED with the host holding it armed (a Disarm retried late)
        self.unasked_arms = 0  # ARMED with the operator's Disarm settled (:meth:`hold_disarmed`)
        self.disarms_resent = 0  # the operator's Disarm sent again to a board that says ARMED
        self.unheeded_arms = 0  # DISARMED with the host's acknowledged Arm settled (:meth:`hold_armed`)
        self.board_logs_unrecorded = 0  # board Log frames beyond BOARD_LOGS_RECORDED_PER_S: counted only
        self._log_records = Throttle(1.0, BOARD_LOGS_RECORDED_PER_S)  # board logs recorded a second
        self._reconnects_seen = 0  # the session's reconnect count at the last ConnectedEvent
        self.operator_disarmed = False
        self._disarm: Command | None = None  # the operator's Disarm, or the host's last repeat of it
        self._armed_unasked = False  # the board says ARMED though the operator's Disarm was settled
        self._arm_unheeded = False  # the board says DISARMED though it acknowledged the host's Arm
        self._rearm: str | Command | None = None  # "pending" or the Arm in flight
        self._operator_arm: Command | None = None  # the operator's Arm in flight
        self._disarm_unseen = False  # the operator's Disarm is out; the board not yet seen out of ARMED
        self._overtaken_by: Command | None = None  # the operator's Arm sent before that Disarm was seen
        self._fresh_after = -math.inf  # telemetry received before this (host s) is from an older session
        self._link = BoardLink.STALE  # nothing seen yet
        self._stale_noted = False  # the stale episode going on is in the journal
        self._started: float | None = None  # the first tick
        # the latest telemetry and its made time as the last view took them (None: none yet)
        self._viewed: tuple[Telemetry | None, float | None] = (None, None)
        self._session_start: float | None = None  # host s: the latest handshake's answer, the board's word
        self._upsets: list[str] = []

    # ------------------------------------------------------------------ events
    def on_events(self, events: Sequence[Any]) -> None:
        """The board client's new events: records, faults, re-arm wishes."""
        for event in events:
            self._on_event(event)

    def _on_event(self, event: Any) -> None:
        t = event.t
        if isinstance(event, StateEvent):
            old = None if event.old is None else event.old.name
            self.events.write(t, "board_state", old=old, new=event.new.name)
            if event.new is not BoardState.ARMED:
                self._disarm_unseen = False
            if event.new is BoardState.FAILSAFE:
                self.failsafes += 1
                after = t > self.journal.ended_at  # heard on the way out: no re-arm follows
                then = "as the run ended" if after else "re-arming"
                logger.warning("board in FAILSAFE at t=%.3f s (link watchdog): %s", t, then)
                self.journal.fault(t, "failsafe")
                self._upset("failsafe")
            elif self._disarmed_unasked(event):
                self.unasked_disarms += 1
                logger.warning("board DISARMED at t=%.3f s by no command of the host's now: re-arming", t)
                self.events.write(t, "unasked_disarm", old=BoardState.ARMED.name)
                why = "a Disarm the host no longer meant (one retried late)"
                self.journal.fault(t, "disarmed", detail=why)
                self._upset("disarmed")
        elif isinstance(event, BoardResetEvent):
            self.resets += 1
            self._fresh_after = t
            # no board in hand since then: the host's first try (one that restarted before its first
            # answer), or the new boot's start by its uptime (a reset found without a stale fault first)
            since = event.no_board_since
            first = {} if since is None else {"no_board_since": since}
            self.events.write(t, "board_reset", cause=event.cause.name, evidence=event.evidence, **first)
            self.journal.fault(t, "reset", outage_from=since, cause=event.cause.name, evidence=event.evidence)
            self._upset("reset")
        elif isinstance(event, LinkLostEvent):
            self.link_losses += 1
            self._fresh_after = t
            self.events.write(t, "link_lost", reason=event.reason)
            self.journal.fault(t, "link_lost", reason=event.reason)
            self._upset("link_lost")
        elif isinstance(event, ConnectedEvent):
            self._session_start = t
            self.events.write(t, "connected", reconnects=event.reconnects)
            if event.reconnects > self._reconnects_seen:  # the session's count: a handshake after a reset
                self._reconnects_seen = event.reconnects  # on a session that reconnected once is not one
                self.reconnects += 1
                self._fresh_after = t
                self.journal.fault(t, "reconnect", reconnects=event.reconnects)
                self._upset("reconnect")
        elif isinstance(event, SilenceEvent):
            self.events.write(t, "silence", since=event.since, ended=event.ended)
        elif isinstance(event, LogEvent):
            self._record_board_log(t, event)

    def _record_board_log(self, t: float, event: LogEvent) -> None:
        """The board's Log into ``events.jsonl``, at most :data:`BOARD_LOGS_RECORDED_PER_S` a second of
        host time: a board flooding its log (20 000 frames in a burst) wrote a flushed line each — the
        run directory grew by megabytes a second, the ground station's feed with it. The rest are counted
        (``board_logs_unrecorded`` in the summary); the next one recorded says how many went before it."""
        before = self._log_records.due(t)
        if before is None:
            self.board_logs_unrecorded += 1
            return
        skipped = {"not_recorded_before": before} if before else {}
        self.events.write(t, "board_log", severity=event.log.severity.name, text=event.log.text, **skipped)

    def _disarmed_unasked(self, event: StateEvent) -> bool:
        """Whether ``event`` is the board leaving ARMED for DISARMED while the host holds it armed: the
        operator has not disarmed it, and no re-arm (after a failsafe, a reset, a link loss) is under way
        that would explain a board out of ARMED. It happens when the operator's Disarm, sent into a stalled
        link, is retried (same sequence number) after the operator's Arm that followed it was carried out:
        the board ends DISARMED while everything on the host says armed — no setpoint moves a motor, and a
        run that was not told would say it completed. (A handshake's BOOT → DISARMED is a reset's, and
        FAILSAFE → DISARMED follows a failsafe already being recovered from.)"""
        if event.new is not BoardState.DISARMED or event.old is not BoardState.ARMED:
            return False
        if self._operators_own_disarm(event.t):
            return False
        return not self.operator_disarmed and self._rearm is None and not self._upsets

    def _operators_own_disarm(self, t: float) -> bool:
        """Whether a board DISARMED at ``t`` (s) is the operator's own Disarm carried out, the Arm the
        operator sent after it (before the board was seen disarmed: both in one control tick, a ground
        station's two clicks) not yet settled :data:`STATE_CONFIRM_S` before: the board carries them out in
        the order sent, so its ARMED → DISARMED → ARMED is what the operator asked for. Taken for an
        unasked Disarm, it was a ``disarmed`` fault, a recovery, and on the run's last tick an exit ``lost …
        for 0.0 s`` (status 3). Once only: a later Disarm no one sent is one. (A board that then stays
        DISARMED has not carried the Arm out: :meth:`hold_armed` says so.)"""
        arm, self._overtaken_by = self._overtaken_by, None
        if arm is None:
            return False
        return arm.settled_at is None or t - arm.settled_at < STATE_CONFIRM_S

    def _upset(self, why: str) -> None:
        self._upsets.append(why)
        if not self.operator_disarmed and self._rearm is None:
            self._rearm = "pending"

    def take_upsets(self) -> list[str]:
        """Why the board left the state the host commanded since the last call (oldest first)."""
        upsets, self._upsets = self._upsets, []
        return upsets

    # ------------------------------------------------------------------ the view
    def view(self, t: float) -> View:
        """The board as the host may use it at ``t``. Telemetry is live while younger than
        ``stale_after_s`` and received after the latest link loss, reconnect or reset; one the reader thread
        took after ``t`` (real time) is not seen yet — the one viewed before it is, with its own time (an age
        is never below 0, and never paired with another message's time). A change of view is
        an ``events.jsonl`` record; going without live telemetry for ``stale_after_s`` (counted from the
        board's last word: its last live telemetry, or the session's handshake, whichever is latest) is a
        ``stale`` fault — the short wait for the first telemetry of a new session is not.

        The fault (and the outage it opens) is dated when that bound passed, not at the tick that saw it:
        the host may have been looking elsewhere then. A board that hung between its handshake and the
        run's first Arm was counted from the first control tick, after the Arm's 0.5 s wait — its outage
        began 0.5 s late (0.86 s, not 0.35 s) and a board never back was declared lost 0.5 s late, its
        outage said 0.5 s shorter than the board's silence."""
        client = self.client
        tel, tel_t = client.latest_telemetry()
        if tel_t is not None and tel_t > t:  # the reader thread took it after this tick took its time (real
            tel, tel_t = self._viewed  # time): its age was below 0; the one viewed last is the newest by t
        else:
            self._viewed = (tel, tel_t)
        age = None if tel_t is None else t - tel_t
        if self._started is None:
            self._started = t
        fresh = tel_t is not None and tel_t > self._fresh_after and t - tel_t <= self.stale_after_s
        if not client.connected:
            link = BoardLink.LOST
        else:
            link = BoardLink.LIVE if fresh else BoardLink.STALE
        if link is not self._link:
            self.events.write(t, "board_link", link=link.name, tel_age_ms=None if age is None else age * 1e3)
            self._link = link
        if link is BoardLink.LIVE:
            self._stale_noted = False
        elif link is BoardLink.STALE and not self._stale_noted:
            since = self._last_word(tel_t)
            if t - since > self.stale_after_s:
                self._stale_noted = True
                self.stale_episodes += 1
                heard = "never" if age is None else f"{age * 1e3:.0f} ms ago"
                logger.warning(
                    "no board telemetry for %.2f s at t=%.3f s (the last: %s)", t - since, t, heard
                )
                stale_at = max(since + self.stale_after_s, self._closed_outage_end())
                self.journal.fault(
                    stale_at, "stale", tel_age_ms=None if tel_t is None else (stale_at - tel_t) * 1e3
                )
        if link is not BoardLink.LIVE:
            return View(link, None, age)
        return View(link, tel, age, tel_t)

    def _last_word(self, tel_t: float | None) -> float:
        """The host time (s) the board's silence is counted from: its last telemetry of this session, or
        the session's handshake (the board's answer to it) when none came since; the run's first tick only
        for a watch that never saw the session start."""
        assert self._started is not None
        session = self._started if self._session_start is None else self._session_start
        return max(session, self._fresh_after, -math.inf if tel_t is None else tel_t)

    def _closed_outage_end(self) -> float:
        """When the last outage the host recovered from ended (s; -inf: none): a new one starts no
        earlier."""
        last = self.journal.outages[-1] if self.journal.outages else None
        return -math.inf if last is None or last.end is None else last.end

    def host_stalled(self, t: float, due: float) -> bool:
        """Whether the host itself stalled before this control tick: it runs at ``t``, more than
        ``stale_after_s`` after its deadline ``due`` (its process paused or swapped out, the machine
        suspended). The host commanded nothing and saw nothing meanwhile — blind longer than the board's
        own link timeout, which fails it safe — so it is a ``host_stall`` fault from the missed deadline,
        an outage the run's bound applies to: a host paused longer than ``--recover-within`` is lost. (It
        was journalled nowhere: the backlog read after the pause hid it, and the run said ``completed``
        with an outage of 0.03 s.)"""
        late = t - due
        if not late > self.stale_after_s:
            return False
        self.host_stalls += 1
        logger.warning("the host stalled: its control tick due at t=%.3f s ran %.2f s late", due, late)
        self.events.write(due, "host_stall", late_ms=late * 1e3)  # at its start: the records in time order
        self.journal.fault(due, "host_stall", late_ms=late * 1e3)
        return True

    def in_control(self, t: float, view: View, phone_fresh: bool) -> bool:
        """Whether the host is in control at ``t``: the board in hand (telemetry live, the board armed — or
        disarmed by the operator — no re-arm pending; a board that says ARMED against the operator's Disarm
        is not in hand) and the phone fresh. The board's open outage ends when the board is in hand,
        whatever the phone: a phone gap is an episode of its own (:meth:`FaultJournal.phone_back` ends
        it). It waited for the phone too, and a board live and armed again at 1.988 s was said "back at
        2.948 s" — the phone's gap counted as the board's, in its outage's end and duration."""
        tel = view.telemetry
        if tel is None or self._rearm is not None or self._armed_unasked:
            return False
        if tel.state is not BoardState.ARMED and not self.operator_disarmed:
            return False
        back = self.journal.board_back(t)
        if back is not None:
            self.events.write(t, "board_back", since=back.start, outage_s=t - back.start, causes=back.causes)
        return phone_fresh

    def hold_disarmed(self, t: float, view: View) -> None:
        """While the operator holds the board disarmed: a board whose live telemetry, made
        :data:`STATE_CONFIRM_S` or more after the operator's Disarm was settled, still says ARMED has not
        carried it out (a board that ignored it, a Disarm lost with no answer, an Arm of an older try that
        reached it later). Its rotors may be spinning while everything the operator sees says disarmed:
        an ``armed`` fault (an outage: a board that never obeys is lost within the run's bound), a warning,
        and the Disarm sent again, as often as it settles with the board still ARMED. The episode ends when
        the board says it is out of ARMED."""
        if not self.operator_disarmed:
            return
        tel, tel_t = view.telemetry, view.made_s
        if tel is None or tel_t is None:
            return  # not live: the view's own faults say so
        if tel.state is not BoardState.ARMED:
            self._armed_unasked = False
            return
        disarm = self._disarm
        if disarm is not None and not disarm.done:
            return  # on its way
        settled = None if disarm is None else disarm.settled_at
        if settled is not None and tel_t - settled < STATE_CONFIRM_S:
            return  # the board may not have said so yet
        if not self._armed_unasked:
            self._armed_unasked = True
            self.unasked_arms += 1
            logger.warning("board ARMED at t=%.3f s though the operator disarmed it: disarming again", t)
            self.events.write(t, "unasked_arm", settled=settled)
            why = "the board says ARMED after the operator's Disarm was settled"
            self.journal.fault(t, "armed", detail=why)
        if self.client.connected:
            self._disarm = self.client.command(Disarm())
            self.disarms_resent += 1
            self.events.write(t, "disarm_resent", seq=self._disarm.seq)

    def hold_armed(self, t: float, view: View) -> None:
        """While the host holds the board armed (the operator has not disarmed it, no re-arm under way): a
        board whose live telemetry, made :data:`STATE_CONFIRM_S` or more after it acknowledged the Arm,
        says DISARMED has not carried the Arm out (a firmware that answered and did nothing, an Arm refused
        in all but its answer). No state change tells it — the host took the acknowledgement for ARMED —
        so before, the first such Arm was caught (its ARMED → DISARMED looked like an unasked Disarm) and
        the re-arm after it was not: the run sat blind with no second Arm until it was lost. Now each
        acknowledged Arm the board did not carry out is a ``disarmed`` fault (once an episode: an outage,
        ``arm_unheeded`` in ``events.jsonl``, a warning) and the Arm is sent again, as often as it is
        acknowledged with the board still DISARMED; a board that never obeys is lost within the run's
        bound. (A board that says FAILSAFE or BOOT is a failsafe's or a reset's, told by its own event.)"""
        if self.operator_disarmed or self._rearm is not None:
            return
        tel, tel_t = view.telemetry, view.made_s
        if tel is None or tel_t is None:
            return  # not live: the view's own faults say so
        if tel.state is not BoardState.DISARMED:
            self._arm_unheeded = False
            return
        acked = self.client.arm_acked_at
        if acked is None or tel_t - acked < STATE_CONFIRM_S:
            return  # not armed by the host yet, or the board may not have said so yet
        if not self._arm_unheeded:
            self._arm_unheeded = True
            self.unheeded_arms += 1
            logger.warning("board DISARMED at t=%.3f s though it acknowledged the Arm: arming again", t)
            self.events.write(t, "arm_unheeded", acked=acked)
            self.journal.fault(t, "disarmed", detail="the board says DISARMED after it acknowledged the Arm")
            self._upsets.append("disarmed")
        self._rearm = "pending"

    # ------------------------------------------------------------------ arming
    @property
    def rearm_pending(self) -> bool:
        return self._rearm is not None

    @property
    def arm_outstanding(self) -> bool:
        """Whether an Arm of the host's may still reach the board: a re-arm sent and not settled, or the
        operator's Arm in flight. A board the host lets go of then must be sent a Disarm after it."""
        rearm, arm = self._rearm, self._operator_arm
        return (isinstance(rearm, Command) and not rearm.done) or (arm is not None and not arm.done)

    def rearm_if_needed(self, t: float, start: bool = True) -> None:
        """Re-arm without blocking the loop: send Arm once a session is up, look at the answer later. An
        operator's Arm that failed (a stall, a reset while it was in flight) is carried on the same way:
        the operator asked for an armed board, and a link fault does not take that back. ``start`` False
        (the run's time is up: this tick is its last) sends no new Arm — a re-arm sent as the host lets go
        of the board left it ARMED with no one commanding it — and only settles one already in flight."""
        arm = self._operator_arm
        if arm is not None and arm.done:
            self._operator_arm = None
            if not arm.ok and not self.operator_disarmed and self._rearm is None:
                self.events.write(t, "rearm_for_operator", detail=str(arm.failure or arm.reason))
                self._rearm = "pending"
        if self._rearm is None or not self.client.connected:
            return
        if self._rearm == "pending":
            if not start:
                return
            self._rearm = self.client.command(Arm())
            self.events.write(t, "rearm_sent", seq=self._rearm.seq)
            return
        assert isinstance(self._rearm, Command)
        if not self._rearm.done:
            return
        try:
            self._rearm.result()
            self.rearms += 1
            self.events.write(t, "rearmed")
            self._rearm = None
        except CommandFailed as exc:  # e.g. still in reset: try again next tick
            self.events.write(t, "rearm_failed", detail=str(exc))
            self._rearm = "pending"

    def request_arm(self) -> None:
        """Arm the board through the protocol on a coming tick (the run's first Arm failed: a fault while
        arming), unless the operator has it disarmed."""
        if not self.operator_disarmed and self._rearm is None:
            self._rearm = "pending"

    def operator_disarm(self, t: float) -> Command:
        """The operator's Disarm: sent now; any re-arm the host had pending is cancelled, and the host does
        not re-arm on its own until :meth:`operator_arm` (the host suspends the run meanwhile)."""
        self.operator_disarmed = True
        if self._rearm is not None:
            self.events.write(t, "rearm_cancelled", reason="disarmed by the operator")
            self._rearm = None
        self._disarm = None  # set once sent: without a session the command raises here
        self._disarm = self.client.command(Disarm())
        self._disarm_unseen = True
        self._overtaken_by = None
        return self._disarm

    def operator_arm(self, t: float) -> Command:
        """The operator's Arm: sent now (should it fail, the host re-arms through the protocol:
        :meth:`rearm_if_needed`); the host re-arms on its own again after later faults."""
        arm = self.client.command(Arm())  # LinkError without a session: then nothing changes here
        self.operator_disarmed = False
        self._disarm = None
        self._armed_unasked = False
        self._rearm = None
        self._operator_arm = arm
        # the operator's Disarm not yet seen carried out: the board's DISARMED to come is that Disarm's
        self._overtaken_by = arm if self._disarm_unseen else None
        self._disarm_unseen = False
        return arm

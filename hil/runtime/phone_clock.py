"""The host's side of the phone's clock: each reading through the admission policy and the clock guard
(:class:`hil.estimation.admission.PhoneGuard`, the policy itself), what the run's record says of it —
dropped readings, a clock that restarted or jumped, a gap in the stream and its end — and whether the
phone is fresh on the control tick. What the host does about it (the estimator started afresh, the
warm-up's still window again) is the host's (:meth:`hil.runtime.host.Host.feed`)."""

from __future__ import annotations

import enum
import logging
import math

from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.sensors import MAX_PAUSE_S, SensorSample
from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog

logger = logging.getLogger(__name__)

MAX_GAP_S = MAX_PAUSE_S  # s: a pause in the phone's stamps longer than this restarts the estimator
DROP_NOTE_S = 0.1  # a reason's dropped readings make at most one journal record per this long (s)


class Freshness(enum.Enum):
    """The phone on one control tick: ``FRESH`` (a sample accepted within ``stale_after_s``, or none has
    come yet), ``GAP_BEGAN`` (none for longer: a fault, noted this tick), ``STALE`` (the gap goes on)."""

    FRESH = "fresh"
    GAP_BEGAN = "gap_began"
    STALE = "stale"


class PhoneClock:
    """The phone stream's clock as the host keeps it (see the module docstring); ``stale_after_s``: a
    phone with no accepted sample for longer is not fresh."""

    def __init__(self, journal: FaultJournal, events: EventLog, stale_after_s: float) -> None:
        self.journal = journal
        self.events = events
        self.stale_after_s = stale_after_s
        self.guard = PhoneGuard()  # the admission policy and the clock guard
        self.count = 0  # accepted samples (the merger's count) seen at the last control tick
        self.heard: float | None = None  # host time (s) the count last moved
        self._drops: dict[str, tuple[float, int]] = {}  # reason -> (last noted at, dropped since)

    def admit(self, sample: SensorSample, now: float | None) -> tuple[Verdict, float]:
        """The guard's verdict on ``sample`` (a dropped one noted: :meth:`_note_drop`), and how far its
        stamp is past the newest reading accepted before it (s, the phone's clock: a pause longer than
        :data:`MAX_GAP_S` is not integrated across). ``now``: the host's time (s), for the record."""
        newest = self.guard.newest
        verdict = self.guard.admit(sample, now)
        if verdict is Verdict.DROP:
            self._note_drop(self.guard.last_reason, now)
        return verdict, sample.t_s - newest

    def reanchored(self, verdict: Verdict, t_s: float, now: float | None) -> tuple[float, str]:
        """The stream's clock moved — restarted (an app restarted, firmware-sim's world started over) or
        jumped forward — and the guard re-anchored on the reading stamped ``t_s``: a fault in the journal
        and ``events.jsonl``, the accepted count from zero (the host starts a new merger). Returns when
        (host s: ``now``, or when the phone was last heard) and which (``phone_restart``, ``phone_jump``;
        ``phone_stray`` when what moved was the stream's first reading, a stray: a dropped reading in the
        record, no clock that moved)."""
        self.count = 0
        t = now if now is not None else (self.heard or 0.0)
        if verdict is Verdict.STRAY:
            self._note_drop(self.guard.last_reason, now)
            return t, "phone_stray"
        kind = "phone_restart" if verdict is Verdict.RESTART else "phone_jump"
        detail = {"newest_s": self.guard.anchored_from, "sample_s": t_s}
        # a fault in the record, but no phone gap: the stream did not pause (the samples flowed on, on a
        # new clock); the host's warm-up again is its answer (counted as ``phone_restarts``)
        self.journal.note(t, kind, **detail)
        self.events.write(t, kind, **detail)
        return t, kind

    def freshness(self, t: float, accepted: int) -> Freshness:
        """Whether the phone's samples are fresh at ``t`` (s), given the merger's ``accepted`` count: a
        count that moved is the phone heard (and the end of a gap, if one was open); a gap
        (no sample for ``stale_after_s``) is a fault, noted when it begins."""
        if accepted != self.count:
            self.count = accepted
            self.heard = t
            back = self.journal.phone_back(t)
            if back is not None:
                self.events.write(t, "phone_back", since=back.start, gap_s=t - back.start)
            return Freshness.FRESH
        heard = self.heard
        if heard is None or t - heard <= self.stale_after_s:
            return Freshness.FRESH
        if self.journal.phone_out is not None:
            return Freshness.STALE
        self.journal.fault(t, "phone_gap", since=heard)
        self.events.write(t, "phone_gap", since=heard)
        logger.warning("no phone sample for %.2f s at t=%.3f s: holding", t - heard, t)
        return Freshness.GAP_BEGAN

    def _note_drop(self, reason: str | None, now: float | None) -> None:
        """A dropped reading into the journal and ``events.jsonl``: the first of each reason, then one
        record per :data:`DROP_NOTE_S` with the count since (a flood makes a few records, not one each).
        Duplicates are the merger's ordinary business (a phone's jitter), not a fault."""
        if reason is None or reason == "duplicate":
            return
        t = now if now is not None else (self.heard or 0.0)
        first, count = self._drops.get(reason, (-math.inf, 0))
        if t - first < DROP_NOTE_S:
            self._drops[reason] = (first, count + 1)
            return
        self._drops[reason] = (t, 0)
        total = self.guard.stats.dropped[reason]
        self.journal.note(t, "readings_dropped", reason=reason, since_last=count + 1, total=total)
        self.events.write(t, "readings_dropped", reason=reason, since_last=count + 1, total=total)
        if count == 0:
            logger.warning("phone reading dropped at t=%.3f s: %s (counted)", t, reason)

"""The host's side of the phone's clock: each reading through the admission policy and the clock guard
(:class:`hil.estimation.admission.PhoneGuard`, the policy itself), what the run's record says of it —
dropped readings, a clock that restarted or jumped, a gap in the stream and its end — and whether the
phone is fresh on the control tick. What the host does about it (the estimator started afresh, the
warm-up's still window again) is the host's (:meth:`hil.runtime.host.Host.feed`)."""

from __future__ import annotations

import enum
import logging
import math
from collections import Counter
from collections.abc import Mapping

from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.sensors import MAX_PAUSE_S, SensorSample
from hil.runtime.faults import FaultJournal
from hil.runtime.phone_cadence import PhoneCadence
from hil.runtime.runlog import EventLog

logger = logging.getLogger(__name__)

MAX_GAP_S = MAX_PAUSE_S  # s: a pause in the phone's stamps longer than this restarts the estimator
DROP_NOTE_S = 0.1  # a reason's dropped readings make at most one journal record per this long (s)
NEEDED = ("gyr", "acc")
"""The sensors the host cannot steer without (``SensorKind.label``): the estimator propagates on the
gyroscope and levels on the accelerometer; the magnetometer may go (heading is then unobserved)."""
FROZEN_READINGS = 10
"""A sensor's readings in a row that repeat its last stamp, none of it accepted since: not a phone's
jitter (one repeat) but a clock that stopped while the phone streams on — recorded and logged as drops."""
_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}


class Freshness(enum.Enum):
    """The phone on one control tick: ``FRESH`` (a gyroscope and an accelerometer sample accepted within
    ``stale_after_s``, or none has come yet), ``GAP_BEGAN`` (not: a fault, noted this tick), ``STALE``
    (the gap goes on)."""

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
        self.count = 0  # accepted samples (the run's, over every merger) seen at the last control tick
        self.heard: float | None = None  # host time (s) the count last moved
        self._drops: dict[str, tuple[float, int]] = {}  # reason -> (last noted at, dropped since)
        self._drops_held = False  # some reason's drops since its last record are not recorded yet
        self._kind_count: dict[str, int] = {}  # per needed sensor: its accepted count at the last tick
        self._kind_heard: dict[str, float] = {}  # per needed sensor: host time (s) its count last moved
        # per sensor: its readings refused since its last accepted one, by reason (why a gap is a gap)
        self._refused: dict[str, Counter[str]] = {}
        self.cadence = PhoneCadence(journal, events, stale_after_s)  # whether it delivers in late batches

    def admit(self, sample: SensorSample, now: float | None) -> tuple[Verdict, float]:
        """The guard's verdict on ``sample`` (a dropped one noted: :meth:`_note_drop`), and how far its
        stamp is past the newest reading accepted before it (s, the phone's clock: a pause longer than
        :data:`MAX_GAP_S` is not integrated across). ``now``: the host's time (s), for the record."""
        newest = self.guard.newest
        verdict = self.guard.admit(sample, now)
        label = sample.kind.label
        if verdict is Verdict.DROP:
            reason = self.guard.last_reason
            refused = self._refused.get(label)
            if refused is None:
                refused = self._refused[label] = Counter()
            refused[reason or "?"] += 1
            if reason == "duplicate" and refused["duplicate"] >= FROZEN_READINGS:
                reason = "clock_stopped"  # not jitter: noted (a duplicate in the counts, as ever)
            self._note_drop(reason, now)
        elif label in self._refused:
            del self._refused[label]
        return verdict, sample.t_s - newest

    def reanchored(self, verdict: Verdict, t_s: float, now: float | None) -> tuple[float, str]:
        """The stream's clock moved — restarted (an app restarted, firmware-sim's world started over) or
        jumped forward — and the guard re-anchored on the reading stamped ``t_s``: a fault in the journal
        and ``events.jsonl`` (the host starts a new merger). Returns when
        (host s: ``now``, or when the phone was last heard) and which (``phone_restart``, ``phone_jump``;
        ``phone_stray`` when what moved was the stream's first reading, a stray: a dropped reading in the
        record, no clock that moved)."""
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

    def freshness(self, t: float, accepted: int, by_kind: Mapping[str, int] | None = None) -> Freshness:
        """Whether the phone's samples are fresh at ``t`` (s), given the run's ``accepted`` count and
        (``by_kind``) its accepted count per sensor — counts over every merger, which never go back (a
        fresh merger's own count from zero would be a count that moved with nothing heard): a count that
        moved is the phone heard (and the
        end of a gap, if one was open). Fresh takes a gyroscope and an accelerometer sample within
        ``stale_after_s`` (:data:`NEEDED`: a phone whose gyro readings are all refused is no phone to
        steer by, though its magnetometer streams); a gap is a fault, noted when it begins, saying why
        when readings came and were refused (:meth:`_why`)."""
        moved = accepted != self.count
        if moved:
            self.cadence.heard(t, self.heard, self.guard.newest)
            self.count = accepted
            self.heard = t
        heard = self.heard
        since = heard
        if by_kind is not None and heard is not None:
            for label in NEEDED:
                n = by_kind.get(label, 0)
                if n != self._kind_count.get(label, 0) or label not in self._kind_heard:
                    self._kind_count[label] = n
                    if n or label not in self._kind_heard:  # never heard: from when the phone first was
                        self._kind_heard[label] = t
                since = min(heard if since is None else since, self._kind_heard[label])
        out = self.journal.phone_out
        if self.cadence.batched_s is not None:  # fresh for a moment at each batch, stale between: not fresh
            if out is not None:
                if "phone_batched" not in out.causes:
                    out.causes.append("phone_batched")
                return Freshness.STALE
            return self._gap_began(t, since, self.cadence.why(), ["phone_batched"])
        if since is None or t - since <= self.stale_after_s:
            if out is not None:
                back = self.journal.phone_back(t)
                assert back is not None
                self.events.write(t, "phone_back", since=back.start, gap_s=t - back.start)
            return Freshness.FRESH
        why, causes = self._why(t)
        if out is not None:
            for cause in causes:  # what the gap turned out to be, for the run's lost message
                if cause not in out.causes:
                    out.causes.append(cause)
            return Freshness.STALE
        logger.warning("no usable phone sample for %.2f s at t=%.3f s: holding (%s)", t - since, t, why)
        return self._gap_began(t, since, why, causes)

    def _gap_began(self, t: float, since: float | None, why: str, causes: list[str]) -> Freshness:
        """A phone gap from ``since`` noticed at ``t``: a fault with ``why`` and its ``causes``. The gap
        opens when the phone stopped being fresh — ``stale_after_s`` after ``since``, its needed samples'
        last — as a board's stale outage does (:meth:`hil.runtime.watch.BoardWatch.view`), not at the tick
        that noticed it: a late tick (a host stall, a slow tick) put the gap's start, and the phone's lost
        bound counted from it, as late as the tick, its ``gap_s`` that much short."""
        opened = None if since is None else since + self.stale_after_s
        self.journal.fault(t, "phone_gap", outage_from=opened, since=since, why=why)
        out = self.journal.phone_out
        assert out is not None  # the fault just opened it
        out.causes.extend(causes)
        self.events.write(t, "phone_gap", since=since, why=why)
        return Freshness.GAP_BEGAN

    def _why(self, t: float) -> tuple[str, list[str]]:
        """Why the phone is not fresh at ``t``, for a user, and the causes to name in the record: for
        each needed sensor not heard within ``stale_after_s``, nothing came, or what came was refused
        and for what — a clock that stopped (its stamps repeated: ``phone_clock_stopped``), went back
        (``phone_clock_back``), runs slow (``phone_clock_slow``), or readings refused for other reasons
        (``phone_readings_refused``)."""
        heard = self.heard
        silent: list[str] = []
        by_cause: dict[str, list[str]] = {}  # cause -> "N gyroscope" parts
        refused_why: list[str] = []
        for label in NEEDED:
            last = self._kind_heard.get(label, heard)
            if last is not None and t - last <= self.stale_after_s:
                continue
            name = _NAMES[label]
            refused = self._refused.get(label)
            if not refused:
                silent.append(name)
                continue
            total = sum(refused.values())
            if refused["duplicate"] == total:
                cause = "phone_clock_stopped"
            elif refused["out_of_order"] + refused["past"] >= total / 2:
                cause = "phone_clock_back"
            elif refused["slow_clock"] >= total / 2:
                cause = "phone_clock_slow"
            else:
                cause = "phone_readings_refused"
                reasons = ", ".join(f"{r} {n}" for r, n in refused.most_common())
                refused_why.append(f"{total} {name} readings came, every one refused ({reasons})")
            by_cause.setdefault(cause, []).append(f"{total} {name}")
        said = [f"no {' and no '.join(silent)} reading came"] if silent else []
        if "phone_clock_stopped" in by_cause:
            said.append(
                f"the phone streams but its clock stopped: {' and '.join(by_cause['phone_clock_stopped'])} "
                "readings repeated their sensor's last time stamp"
            )
        if "phone_clock_back" in by_cause:
            said.append(
                f"the phone's clock went back: {' and '.join(by_cause['phone_clock_back'])} readings "
                "stamped before their sensor's last (dropped: out_of_order, past)"
            )
        if "phone_clock_slow" in by_cause:
            said.append(
                "the phone's clock runs slow against the host's: "
                f"{' and '.join(by_cause['phone_clock_slow'])} readings refused (slow_clock): integrated, "
                "they would turn the attitude at its clock's rate"
            )
        said += refused_why
        return ("; ".join(said) or "no reading came"), list(by_cause)

    def _note_drop(self, reason: str | None, now: float | None) -> None:
        """A dropped reading into the journal and ``events.jsonl``: the first of each reason, then one
        record per :data:`DROP_NOTE_S` with the count since (a flood makes a few records, not one each;
        what a window holds back is recorded by :meth:`note_held_drops`). A duplicate is a phone's jitter,
        not a fault: not noted — unless a sensor's stamps stopped (:data:`FROZEN_READINGS` repeats, none
        accepted between), noted as ``clock_stopped``."""
        if reason is None or reason == "duplicate":
            return
        t = now if now is not None else (self.heard or 0.0)
        first, count = self._drops.get(reason, (-math.inf, 0))
        if t - first < DROP_NOTE_S:
            self._drops[reason] = (first, count + 1)
            self._drops_held = True
            return
        self._record_drops(t, reason, count + 1)
        if reason == "clock_stopped" and count == 0:
            logger.warning(
                "phone readings dropped at t=%.3f s: they repeat their sensor's last time stamp, %d in a "
                "row: the phone streams but its clock stopped (counted as duplicate)",
                t,
                FROZEN_READINGS,
            )
        elif count == 0:
            logger.warning("phone reading dropped at t=%.3f s: %s (counted)", t, reason)

    def note_held_drops(self, t: float, final: bool = False) -> None:
        """Record the drops :meth:`_note_drop`'s rate limit held back, once :data:`DROP_NOTE_S` has passed
        since their reason's last record (each control tick), or all of them (``final``: the run's end).
        Without it a burst inside one window — 500 readings beyond the gyro's bound in a row, 21 of a
        clock that jumped — made one record, of its first reading, and the rest reached only the summary's
        counts."""
        if not self._drops_held:
            return
        self._drops_held = False
        for reason, (first, count) in list(self._drops.items()):
            if not count:
                continue
            if final or t - first >= DROP_NOTE_S:
                self._record_drops(t, reason, count)
            else:
                self._drops_held = True

    def _record_drops(self, t: float, reason: str, since_last: int) -> None:
        """One ``readings_dropped`` record at ``t``: ``since_last`` readings of ``reason`` since its last."""
        self._drops[reason] = (t, 0)
        total = self.guard.stats.dropped["duplicate" if reason == "clock_stopped" else reason]
        self.journal.note(t, "readings_dropped", reason=reason, since_last=since_last, total=total)
        self.events.write(t, "readings_dropped", reason=reason, since_last=since_last, total=total)

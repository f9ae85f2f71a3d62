"""What went wrong during a run and whether the host had the board in hand: the host's view of the board
(:class:`BoardLink`, by the age of its telemetry) and the run's fault journal (:class:`FaultJournal`).

**The view has an age.** The host's copy of the board's telemetry is *live* only while it is younger than
``stale_after_s`` (default :data:`STALE_AFTER_S`, the board's own link timeout: a board that has not
heard the host for that long fails safe) and came from the session in force (not from before a link loss,
a reconnect or a reset). Otherwise it is *stale* (a session, but nothing heard: an MCU hang, a brown-out,
a stalled or damaged link) or the link is *lost* (no session: the port vanished, the client reconnects or
handshakes again). A telemetry row that is not live carries no board value at all — never the last ones
repeated as fresh — and says how old the last telemetry is (``tel_age_ms``) and why (``board_link``).

**Outages.** An outage starts with the first sign that the host no longer commands the board (its
telemetry goes stale, the link is lost, the board fails safe or resets) and ends when the host has the
board in hand again: telemetry live, the board armed again through the protocol (a new handshake first,
after a loss or a reset) — whatever the phone. A phone gap (no sample for ``stale_after_s``) is recorded
the same way, as an episode of its own with its own times: the board's outage does not wait for the
phone's return (a board back at 1.988 s was said back at 2.948 s, the phone's gap counted as the board's).
Every fault goes into :attr:`FaultJournal.faults` (bounded: beyond :data:`MAX_FAULTS` records they are
counted, not kept) with its time and cause; an outage or phone gap longer than ``bound_s`` means the run
lost the board (or the phone): :meth:`FaultJournal.overdue` says so, and the run ends with a non-zero exit
(:mod:`hil.runtime.loop`, ``hil run``'s exit status 3).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

STALE_AFTER_S = 0.25
"""s: board telemetry or phone samples older than this are not live (the board's default link timeout)."""
RECOVER_WITHIN_S = 15.0
"""s: the default bound on an outage (or a phone gap): a run whose board is not back within it is lost."""
MAX_FAULTS = 10_000  # fault records kept per run; more are counted (a soak of thousands of cycles)


class BoardLink(enum.IntEnum):
    """The host's view of the board (``telemetry.csv`` column ``board_link``)."""

    LIVE = 0  # telemetry younger than stale_after_s, from the session in force
    STALE = 1  # a session, but no telemetry for stale_after_s (or none since the session began)
    LOST = 2  # no session: the port vanished, the client reconnects or handshakes again


@dataclass
class Outage:
    """One stretch without the board (or the phone) in hand: from ``start`` to ``end`` (None: still on),
    host clock s; ``causes`` the faults seen meanwhile (their kinds, first seen first)."""

    start: float
    causes: list[str] = field(default_factory=list)
    end: float | None = None

    def duration(self, now: float) -> float:
        return (self.end if self.end is not None else now) - self.start

    def as_dict(self, now: float) -> dict[str, Any]:
        return {
            "start": self.start,
            "end": self.end,
            "duration_s": self.duration(now),
            "causes": list(self.causes),
            "recovered": self.end is not None,
        }


_LOST_AFTER_THE_RUN = {"reset": "reset", "link_lost": "link lost", "failsafe": "failed safe"}
"""The faults heard on the way out that say the board was out of the host's hand at the run's end (by
fault kind: how the exit says it)."""


class FaultJournal:
    """The run's faults, board outages and phone gaps; see the module docstring. All times on the host's
    clock (s). Plain lists, appended to on the control tick: a few attribute writes per fault."""

    def __init__(self, bound_s: float = RECOVER_WITHIN_S) -> None:
        self.bound_s = bound_s
        self.faults: list[dict[str, Any]] = []
        self.dropped = 0
        self.outages: list[Outage] = []
        self.phone_gaps: list[Outage] = []
        self.ended_at = math.inf  # host time (s) the run's loop ended: later faults open no outage

    def end(self, t: float) -> None:
        """The run's loop ended at ``t`` (s): a fault heard later — on the way out, its final Disarm
        finding the board reset — is in the record (``after_the_run``), and no outage or gap of the run."""
        self.ended_at = t

    # ------------------------------------------------------------------ recording
    def fault(self, t: float, kind: str, *, outage_from: float | None = None, **detail: Any) -> None:
        """A fault of ``kind`` (``stale``, ``link_lost``, ``failsafe``, ``reset``, ``reconnect``,
        ``disarmed``, ``phone_gap``) at ``t``: a board fault opens an outage (or joins the open one), a
        phone gap a phone gap. (A phone clock that restarted or jumped is a :meth:`note`: the stream did
        not pause.) ``outage_from`` (s, at most ``t``): the outage it opens began then, the host having had
        no board since (a board that restarted before it answered the first handshake: told at its answer,
        silent from the start; a reset found in a session without a stale fault first: since its new boot
        began, by its uptime — not from its detection)."""
        if t > self.ended_at:
            self.note(t, kind, after_the_run=True, **detail)
            return
        if len(self.faults) < MAX_FAULTS:
            self.faults.append({"t": t, "kind": kind, **detail})
        else:
            self.dropped += 1
        gaps = kind == "phone_gap"
        episodes = self.phone_gaps if gaps else self.outages
        if not episodes or episodes[-1].end is not None:
            start = t if outage_from is None else min(t, outage_from)
            last_end = episodes[-1].end if episodes else None
            episodes.append(Outage(start if last_end is None else max(start, last_end)))  # none overlap
        causes = episodes[-1].causes
        if kind not in causes:
            causes.append(kind)

    def note(self, t: float, kind: str, **detail: Any) -> None:
        """A fault of ``kind`` at ``t`` that opens no outage: the host stays in control through it (readings
        dropped by the admission policy, a dead ESC the board reported) — in the record, with its cause."""
        if len(self.faults) < MAX_FAULTS:
            self.faults.append({"t": t, "kind": kind, **detail})
        else:
            self.dropped += 1

    def board_back(self, t: float) -> Outage | None:
        """The host has the board in hand again at ``t``: the open outage ends (returned), if any."""
        return _close(self.outages, t)

    def phone_back(self, t: float) -> Outage | None:
        """Phone samples flow again at ``t``: the open phone gap ends (returned), if any."""
        return _close(self.phone_gaps, t)

    # ------------------------------------------------------------------ questions
    @property
    def board_out(self) -> Outage | None:
        """The outage going on, if any."""
        return self.outages[-1] if self.outages and self.outages[-1].end is None else None

    @property
    def phone_out(self) -> Outage | None:
        return self.phone_gaps[-1] if self.phone_gaps and self.phone_gaps[-1].end is None else None

    def overdue(self, now: float) -> str | None:
        """Why the run has lost the board (or the phone) at ``now``: an outage (or a gap) longer than
        the bound; None while everything is within it."""
        for what, episode in (("board", self.board_out), ("phone", self.phone_out)):
            if episode is not None and episode.duration(now) > self.bound_s:
                return self._lost(what, episode, now, f"not back within {self.bound_s:g} s")
        return None

    def open_at_end(self, now: float) -> str | None:
        """Why the run ended without the board (or the phone) in hand, if it did."""
        for what, episode in (("board", self.board_out), ("phone", self.phone_out)):
            if episode is not None:
                return self._lost(what, episode, now, "not back when the run ended")
        return None

    def lost_after_the_run(self) -> str | None:
        """Why the board was not in hand at the run's end though no outage was open then: the way out
        heard it had reset, lost the link or failed safe — a board that browned out 0.2 s before the end,
        its telemetry not yet stale; a link stalled over the end, the board's watchdog firing after the
        last tick (nothing of the host's had reached it since before the end) — or None."""
        for f in self.faults:
            if f.get("after_the_run") and f["kind"] in _LOST_AFTER_THE_RUN:
                what, said = _LOST_AFTER_THE_RUN[f["kind"]], str(f.get("reason", ""))
                if f["kind"] == "reset":
                    said = f"cause {f['cause']}"
                elif f["kind"] == "failsafe":
                    said = "its link watchdog"
                return (
                    f"board {what} as the run ended ({said}; "
                    f"heard on the way out at t={f['t']:.3f} s): not back when the run ended"
                )
        return None

    @staticmethod
    def _lost(what: str, episode: Outage, now: float, why: str) -> str:
        causes = ", ".join(episode.causes)
        return f"{what} lost at t={episode.start:.3f} s for {episode.duration(now):.1f} s ({causes}): {why}"

    def summary(self, now: float) -> dict[str, Any]:
        """For ``summary.json``: every fault, every outage and phone gap, and the bound."""
        return {
            "faults": list(self.faults),
            "faults_not_kept": self.dropped,
            "outages": [o.as_dict(now) for o in self.outages],
            "phone_gaps": [o.as_dict(now) for o in self.phone_gaps],
            "recover_within_s": self.bound_s,
        }


def _close(episodes: list[Outage], t: float) -> Outage | None:
    if episodes and episodes[-1].end is None:
        episodes[-1].end = t
        return episodes[-1]
    return None

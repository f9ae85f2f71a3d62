"""Whether the phone delivers its readings in batches spaced beyond the host's stale bound (Sensor
Logger's HTTP Push period set to 0.5 s): each batch then ends a phone gap, and each gap restarted the
warm-up — 93 gaps, a warning every 0.5 s, the slew never started. After :data:`BATCHED_GAPS` such gaps
the phone is *batched*: said once (a warning, ``phone_batched`` in the events and the journal) with what
to set in the app, and :class:`hil.runtime.phone_clock.PhoneClock` keeps one gap open across its batches
— the host still never steers on an estimate older than the bound, and a phone that stays batched is
lost within ``--recover-within``, saying why."""

from __future__ import annotations

import logging
import math

from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog

logger = logging.getLogger(__name__)

BATCHED_GAPS = 3
"""Gaps in a row, each longer than ``stale_after_s``, seen by the host (it looked and found the phone
stale: a phone gap opened) and ended by readings that span it (the phone's clock went on: it streamed,
and delivered late, in one batch), before the host calls the phone batched (an HTTP Push period above the
stale bound) rather than pausing."""
BATCHED_CLEAR_S = 1.0
"""s: a batched phone is taken for a streaming one again once its readings came at most
``stale_after_s`` apart for this long (the app's period shortened), not on one short interval (two late
batches arriving together)."""


class PhoneCadence:
    """See the module docstring. ``stale_after_s``: the host's stale bound (s)."""

    def __init__(self, journal: FaultJournal, events: EventLog, stale_after_s: float) -> None:
        self.journal = journal
        self.events = events
        self.stale_after_s = stale_after_s
        self.batched_s: float | None = None  # the phone's batch period (s) while it is batched, else None
        self._heard_newest = -math.inf  # the phone's newest stamp when its count last moved
        self._batched_run = 0  # gaps in a row that were batches
        self._short_since: float | None = None  # host s: since when a batched phone's intervals are short

    def heard(self, t: float, previous: float | None, newest: float) -> None:
        """The phone's accepted count moved at ``t`` (host s), the last time before at ``previous`` (None:
        the first), its newest stamp now ``newest`` (phone s). Called before the gap this ends is closed:
        an interval longer than the stale bound is a batch only if the host looked in between and found
        the phone stale (a phone gap open in the journal) — what a batched phone does to the host; an
        interval the host did not look into (it looks once a control period) is no batch."""
        advance = newest - self._heard_newest
        self._heard_newest = newest
        if previous is None:
            return
        interval = t - previous
        if interval <= self.stale_after_s or self.journal.phone_out is None:
            # Readings at most the bound apart, or further apart but with no gap the host saw: it found
            # the phone fresh each time it looked (a controller slower than 1 / the bound looks once a
            # period, 0.5 s at 2 Hz, and finds the readings of the whole period each time). Counting those
            # intervals as batches called a streaming phone batched, and every such run lost it.
            self._batched_run = 0
            if self.batched_s is not None:
                self._short_since = previous if self._short_since is None else self._short_since
                if t - self._short_since >= BATCHED_CLEAR_S:
                    self.batched_s = self._short_since = None
                    self.events.write(t, "phone_unbatched", stale_after_s=self.stale_after_s)
                    logger.info("phone readings come at most %.2f s apart again at t=%.3f s", interval, t)
            return
        self._short_since = None
        if not advance >= 0.5 * interval:  # a pause: the phone's clock did not go on (or moved)
            self._batched_run = 0
            return
        self._batched_run += 1
        if self.batched_s is not None:
            self.batched_s = interval
        elif self._batched_run >= BATCHED_GAPS:
            self.batched_s = interval
            detail = {"period_s": round(interval, 3), "stale_after_s": self.stale_after_s}
            self.journal.note(t, "phone_batched", **detail)
            self.events.write(t, "phone_batched", **detail)
            logger.warning("%s", self.why())

    def why(self) -> str:
        """What a batched phone does, and what to set in the app, for a user."""
        return (
            f"the phone delivers its readings in batches every ~{self.batched_s or 0.0:.2f} s, above the "
            f"{self.stale_after_s:.2f} s the host lets a reading age before it calls the phone stale: it "
            "cannot steer on them; set the app's batch period shorter (Sensor Logger: Settings > Data "
            "Streaming > HTTP Push, its batch period at 0.1 s or less)"
        )

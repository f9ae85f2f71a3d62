"""Whether the board's own counts — its uptime (``Telemetry.time_ms``, ``Heartbeat.time_ms``) and its
count of frames taken from the host (``Telemetry.rx_frames``) — moved on by an amount the board could
have reached, sans-IO (every call takes the host's ``now``).

Why: the session's reset detector takes a count that *goes back* as a board reset (and handshakes again,
which disarms the board). A well-formed frame carrying a count far *ahead* (uptime 2e9 ms five seconds
into a run: a corrupted build, a replayed frame of another board, a hostile far side) used to become the
reference the next honest sample was compared with — that sample then "went back", and one absurd frame
made a spurious reset, disarming an armed board mid-run, while its telemetry was shown as live. Now such
a sample is refused (the session drops the frame and counts it).

What "could have reached" means, from an *anchor* sample (the first one of the board's boot, or the one a
reset or a re-anchoring started from):

* uptime: no further ahead than the host's clock moved since the anchor, run ``CLOCK_RATE`` fast, plus
  ``UPTIME_SLACK_MS`` (the anchor frame's own latency — read late by a paused host — and a board clock
  ahead of real time for a moment, e.g. simavr catching up its pacing);
* frames taken: no more than the frames the host has written since the anchor, plus ``FRAMES_SLACK``
  (the host's frames already in flight when the anchor was sent).

The anchor is not the last sample: measured from the last sample, a burst of frames each a little ahead
(all read at the same ``now``) would climb without bound. Nor is it fixed for good: a board's clock off by
more than ``CLOCK_RATE`` — an uncalibrated RC oscillator is off by up to 10 % — drew away from a fixed
anchor until its honest samples passed the slack (after 55 s at 10 % fast, 8 min at 2 %), then had a
second of its telemetry refused, and again a minute later, for the whole run. So every ``SLIDE_AFTER_S``
of host time the anchor moves on to the last sample of an earlier read (the freshest of its burst: a
backlog read at once after a pause is anchored on its newest frame, not its oldest), and a clock off by
less than 50 % never draws ``UPTIME_SLACK_MS`` away from it. Should the anchor itself be the absurd
one (the board's very first sample), every honest sample would be refused from then on; so when samples
have been refused for ``REANCHOR_AFTER_S`` of host time with none taken in between, the board is
consistent with itself and the anchor is what is wrong: the sample is let through and anchors the counts
from then on (the session counts and logs the re-anchoring).
"""

from __future__ import annotations

from dataclasses import dataclass

_U32 = 1 << 32
_HALF = _U32 // 2

ACROSS_WRAP = 10_000
"""How far (ms, or frames) a count may go back across its wrap: a Telemetry made just before a board's
uptime wraps (49.7 days up), overtaken by a Heartbeat made just after it, went back by a few ms — it was
taken as on by 49 days, and refused as a leap. Further back across the wrap is a leap ahead, as ever (a
count of 10 followed by 3·10⁹ is no count that went back by 1.3·10⁹)."""


def went_back(last: int, now: int) -> bool:
    """Whether a board's u32 count (its uptime in ms, its frames taken) went back from ``last`` to ``now``
    rather than on: below it by less than half the count's range, or above it by all but at most
    :data:`ACROSS_WRAP` (back across the wrap)."""
    if now < last:
        return last - now < _HALF
    return 0 < (last - now) % _U32 <= ACROSS_WRAP


def behind(newest: int, now: int) -> int:
    """How far (the count's units) ``now`` is behind ``newest``, modulo 2³² (see :func:`went_back`)."""
    return (newest - now) % _U32


CLOCK_RATE = 1.01
"""How fast a board's clock may run against the host's: 1 % (ten times a cheap resonator's tolerance)."""
UPTIME_SLACK_MS = 5_000
"""How far (ms) a board's uptime may lead the host's clock beyond the anchor's lead."""
FRAMES_SLACK = 1_000
"""Frames of the host's the board may count beyond those written since the anchor (in flight then)."""
REANCHOR_AFTER_S = 1.0
"""Host time (s) of refused samples, none taken between, after which the anchor is taken to be wrong."""
SLIDE_AFTER_S = 10.0
"""Host time (s) after which the uptime's anchor moves on to a sample taken since (see the module)."""


@dataclass
class _Count:
    """One of the board's u32 counts, unwrapped: the last value taken (raw and unwrapped) and its anchor
    (unwrapped value, and the host's measure when it was taken: its time, or its count of frames
    written)."""

    raw: int
    value: int
    anchor_value: int
    anchor_host: float

    @classmethod
    def start(cls, raw: int, host: float) -> _Count:
        return cls(raw, raw, raw, host)

    def ahead(self, raw: int) -> int | None:
        """``raw`` unwrapped against the last value taken, if it moved on (None: it went back — by less
        than half the range, the session's rule — which is the reset detector's business, not a leap)."""
        if went_back(self.raw, raw):
            return None
        return self.value + (raw - self.raw) % _U32

    def take(self, raw: int) -> None:
        value = self.ahead(raw)
        self.value = value if value is not None else raw
        self.raw = raw


@dataclass
class LeapCheck:
    """The board's uptime and frame count against their anchors (see the module docstring). The session
    asks :meth:`refusal` about each sample, then either takes it (:meth:`take`) or, when the board reset
    or :attr:`reanchoring` is set, anchors the counts on it (:meth:`restart`)."""

    uptime: _Count | None = None
    frames: _Count | None = None
    refusing_since: float | None = None  # host time of the first refused sample since one was taken
    reanchoring: bool = False  # the sample refusal() just let through ends a long run of leaps
    # the last uptime taken (unwrapped), the host time it was read and the host time it was made
    last: tuple[int, float, float] | None = None

    def refusal(self, uptime_ms: int, rx_frames: int | None, frames_out: int, now: float) -> str | None:
        """Why this sample leaps ahead of what the board could have reached; None when it could have, or
        when samples have been refused for ``REANCHOR_AFTER_S`` (then :attr:`reanchoring` is set: the
        anchor was the absurd one)."""
        self.reanchoring = False
        why = self._leap(uptime_ms, rx_frames, frames_out, now)
        if why is None:
            return None
        if self.refusing_since is None:
            self.refusing_since = now
        if now - self.refusing_since >= REANCHOR_AFTER_S:
            self.reanchoring = True
            return None
        return why

    def take(
        self, uptime_ms: int, rx_frames: int | None, frames_out: int, now: float, made: float | None = None
    ) -> None:
        """A sample accepted, read at ``now`` and made at host time ``made`` (default ``now``; earlier for a
        backlog, :mod:`.made_at`): the counts move on (the first one of each anchors it). An anchor holds
        the time the sample was made: one on an old frame read late, at its read, left the board's fresh
        samples after it seconds "ahead" — refused as leaps after a host paused over 5 s."""
        made = now if made is None else made
        self.refusing_since = None
        if self.uptime is None:
            self.uptime = _Count.start(uptime_ms, made)
        else:
            self._slide(now)
            self.uptime.take(uptime_ms)
        self.last = (self.uptime.value, now, made)
        if rx_frames is not None:
            if self.frames is None:
                self.frames = _Count.start(rx_frames, frames_out)
            else:
                self.frames.take(rx_frames)

    def restart(
        self, uptime_ms: int, rx_frames: int | None, frames_out: int, now: float, made: float | None = None
    ) -> None:
        """The board restarted (or the anchor was wrong): this sample anchors its counts."""
        self.uptime = self.frames = self.last = None
        self.take(uptime_ms, rx_frames, frames_out, now, made)

    def _slide(self, now: float) -> None:
        """The uptime's anchor moved on to the last sample taken, if it came in an earlier read (so it was
        the newest of its read) at least :data:`SLIDE_AFTER_S` after the anchor."""
        count, last = self.uptime, self.last
        if count is None or last is None:
            return
        value, read_at, made = last
        if read_at < now and made - count.anchor_host >= SLIDE_AFTER_S:
            count.anchor_value, count.anchor_host = value, made

    def _leap(self, uptime_ms: int, rx_frames: int | None, frames_out: int, now: float) -> str | None:
        count = self.uptime
        if count is not None:
            value = count.ahead(uptime_ms)
            reach = (now - count.anchor_host) * 1000.0 * CLOCK_RATE + UPTIME_SLACK_MS
            if value is not None and value - count.anchor_value > reach:
                return (
                    f"its uptime leapt from {count.raw} ms to {uptime_ms} ms, {value - count.anchor_value} "
                    f"ms past its anchor, in {now - count.anchor_host:.3f} s of the host's time"
                )
        count = self.frames
        if count is not None and rx_frames is not None:
            value = count.ahead(rx_frames)
            written = frames_out - int(count.anchor_host)
            if value is not None and value - count.anchor_value > written + FRAMES_SLACK:
                return (
                    f"its count of frames taken leapt from {count.raw} to {rx_frames}, "
                    f"{value - count.anchor_value} past its anchor, when the host wrote {written} since"
                )
        return None

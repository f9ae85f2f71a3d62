"""What a phone reading must be to reach the estimator: the admission policy and the phone's clock guard,
applied where samples enter the host (:meth:`hil.runtime.host.Host.feed`: every live source and a
recording played to a board alike). Pure logic, no I/O.

A reading is **dropped and counted by reason** (:class:`AdmissionStats`) when it

==================  =====================================================================================
reason              the reading
==================  =====================================================================================
``bad_time``        has a time stamp that is not a finite number
``non_finite``      has a value that is NaN or infinite
``out_of_range``    exceeds its sensor's physical range (:class:`ReadingLimits`: a phone gyro saturates
                    near 35 rad/s, an accelerometer near 16 g, a magnetometer near 5 mT) — a value
                    that parses but no phone can measure
``future``          is stamped more than :data:`JUMP_S` after the stream's newest reading plus the host
                    time since it came (a stray, or the first of a clock that jumped forward: see
                    below; a stream that paused and resumes is not ahead of its clock) — or more than
                    :data:`JUMP_S` ahead of the host's clock, against the reading that came with the
                    least delay (its reference sliding ahead by at most :data:`CLOCK_RATE_SLACK` of
                    the host's time: a phone's clock that runs fast, each stamp within a second of the
                    last but 0.9 s on per 5 ms, is not integrated as if time had passed)
``past``            is stamped more than :data:`JUMP_S` before the newest (a stray, or the first of a
                    clock that restarted)
``duplicate``       repeats the time stamp of the last reading of its sensor
``out_of_order``    is stamped before the last reading of its sensor (within :data:`JUMP_S` of the
                    newest): a datagram that overtook another, or a clock stepped back a little (NTP)
``burst``           comes less than :data:`MIN_INTERVAL_S` after the last reading of its sensor: faster
                    than any phone samples (a flood of plausible readings)
``slow_clock``      comes from a stream whose clock runs slow against the host's: the least
                    host-minus-stamp offset of its readings grew by more than :data:`CLOCK_RATE_SLACK`
                    of the host's time in each of :data:`SLOW_WINDOWS` windows in a row (a phone's
                    clock at half speed had every reading accepted, the rotation integrated at half
                    its rate); dropped until a window's least offset stops growing
==================  =====================================================================================

**The clock guard.** A stream whose clock really moved — an app restarted (its clock back at zero), a
phone whose clock was stepped — is *re-anchored*, never on one reading: only after
:data:`REANCHOR_READINGS` readings in a row stamped beyond :data:`JUMP_S` on the same side of the newest,
going forward, each within :data:`JUMP_S` of the one before, and spanning at least :data:`REANCHOR_SPAN_S`
of their own clock (a stream, not a burst of strays: copies of one far stamp span nothing, and strays at
two far stamps — 100 s ahead, then 10⁹ s ahead — are two runs, not one). :meth:`PhoneGuard.admit`
then answers ``RESTART`` (backwards) or ``JUMP`` (forwards): the caller starts the estimator afresh from
the measurements instead of integrating across the jump, and warms up again. Readings the guard dropped
before it re-anchored are counted (``past`` / ``future``).

**An anchor no reading confirmed.** The stream's first reading anchors its clock unseen. Should no
reading of that clock follow it — the stream's first reading was a stray, 100 s ahead, say — the run of
readings that moves the anchor is the stream, and the anchor was the stray: :meth:`PhoneGuard.admit`
answers ``STRAY``, the anchor is counted dropped (``future`` or ``past``, not accepted), and no clock
restart is told (the caller starts its estimator afresh all the same: the stray reached it).
"""

from __future__ import annotations

import enum
import math
import sys
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from hil.estimation.sensors import KINDS, SensorKind, SensorSample

JUMP_S = 1.0
"""s: a reading this far from the stream's newest (either way) is not part of the stream as it was."""
REANCHOR_READINGS = 10
"""Readings in a row beyond :data:`JUMP_S`, on one side, before the guard believes the clock moved ..."""
REANCHOR_SPAN_S = 0.05
"""... spanning this much of their own clock (s)."""
CLOCK_RATE_SLACK = 0.1
"""s per s of host time: how fast the reference of the phone's clock against the host's (the least
host-minus-stamp offset of the readings accepted) may slide ahead on readings that come earlier than it.
A phone's clock keeps the host's to parts per million and a network only ever delays a reading, so a
stream that gains on the host's clock by more than this, for :data:`JUMP_S`, runs fast: its readings are
``future``, and a stream of them re-anchors the clock (``JUMP``) as a jump would. A delay that shrinks
by more than :data:`JUMP_S` at once (a stream that started behind a backlog) is taken for one jump."""
SLOW_WINDOW_S = 1.0
"""s of host time: the window over which the least host-minus-stamp offset of a stream's readings is taken
to judge whether its clock runs slow. The least, not each reading's: a network that stalls and then
delivers what it held delays the held readings, never the last ones of the burst, so the least offset of a
window holds still through a stall; only a clock that falls behind moves it window after window."""
SLOW_WINDOWS = 3
"""Windows in a row whose least offset grew on the one before by more than :data:`CLOCK_RATE_SLACK` of
their host time before a stream's clock is taken to run slow (one growth is a clock that paused once, or
a delay that set in: its offsets then hold, and the stream is taken as it is)."""
MIN_INTERVAL_S = 1e-4
"""s: readings of one sensor closer than this are a flood, not a phone (10 kHz; phones sample ≤ 500 Hz)."""


@dataclass(frozen=True)
class ReadingLimits:
    """The largest magnitude of any axis each sensor can measure: gyroscope rad/s, accelerometer m/s²,
    magnetometer µT. The defaults are a phone's (±2000 °/s ≈ 35 rad/s, ±16 g, ±4.9 mT) with a margin;
    configurable per source."""

    gyr: float = 40.0
    acc: float = 16.0 * 9.80665 * 1.1
    mag: float = 5000.0

    def limit(self, kind: SensorKind) -> float:
        return self.gyr if kind is SensorKind.GYR else self.acc if kind is SensorKind.ACC else self.mag


class Verdict(enum.Enum):
    ACCEPT = "accept"
    DROP = "drop"
    RESTART = "restart"  # the stream's clock went back: re-anchored on this reading
    JUMP = "jump"  # the stream's clock jumped forward: re-anchored on this reading
    STRAY = "stray"  # the reading anchored on was a stray (none of its clock followed): re-anchored here


REASONS = (
    "bad_time",
    "non_finite",
    "out_of_range",
    "future",
    "past",
    "duplicate",
    "out_of_order",
    "burst",
    "slow_clock",
)
"""Why a reading is dropped. ``out_of_order`` is the merger's own reason, checked here first: a reading
the admission let through and the merger then dropped went to no count of ``summary.json``'s
``phone_admission`` (issue: a reordered UDP stream lost 1 in 12 readings, "accepted")."""


@dataclass
class AdmissionStats:
    """Readings accepted, dropped by reason (:data:`REASONS`), and the clock's re-anchorings."""

    accepted: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REASONS, 0))
    restarts: int = 0
    jumps: int = 0

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())


class PhoneGuard:
    """The admission policy and clock guard of one phone stream (see the module docstring)."""

    def __init__(self, limits: ReadingLimits | None = None) -> None:
        self.limits = limits if limits is not None else ReadingLimits()
        self.stats = AdmissionStats()
        self.newest = -math.inf  # the stream's newest accepted time stamp (its own clock, s)
        self.last_reason: str | None = None  # why the last dropped reading was dropped
        self.anchored_from = -math.inf  # the newest stamp of the clock the last re-anchoring left
        self._newest_at = -math.inf  # host time (s) the newest reading came
        # the reference of the stream's clock against the host's: the least host-minus-stamp offset (s)
        # of the readings accepted (NaN: none with a host time), slid ahead since _offset_at (host s)
        self._offset = math.nan
        self._offset_at = 0.0
        self._last: dict[SensorKind, float] = {}
        self._confirmed = True  # a reading of the anchor's clock came after it (none yet: no anchor)
        self._anchor_t = -math.inf  # the anchor's stamp (its own clock, s)
        self._unconfirmed = 0  # readings accepted at the anchor's stamp while it is unconfirmed
        self._run_side = 0  # -1: readings in a row before the newest, +1: after it, 0: none
        self._run_count = 0
        self._run_first = self._run_last = 0.0
        self._limits_of: ReadingLimits | None = None  # the limits _bounds was made from
        # the slow-clock judge (SLOW_WINDOW_S): the window's start (host s), the least offset in it (s), the
        # previous window's (NaN: none), the growths in a row, and whether the clock is taken to run slow
        self._window_at = -math.inf
        self._window_least = math.inf
        self._last_least = math.nan
        self._growths = 0
        self.slow = False
        self._bounds: tuple[float, ...] = ()

    def admit(self, sample: SensorSample, now: float | None = None) -> Verdict:
        """The verdict on one reading (readings in time order within a batch, as they arrived); ``now``
        (s, the host's clock; None: not known) lets a stream that paused resume with stamps as far ahead
        as the pause was long."""
        t = sample.t_s
        xyz = sample.xyz
        limits = self.limits
        if limits is not self._limits_of:  # the per-sensor bounds, by SensorKind, for the check below
            # capped at the largest float: an infinite limit still lets no infinite value through here
            self._limits_of = limits
            self._bounds = tuple(min(limits.limit(kind), sys.float_info.max) for kind in KINDS)
        bound = self._bounds[sample.kind]
        # A reading plainly valid — a finite stamp, three values each within a finite bound, so finite —
        # needs no reason looked for (every reading of a working phone); any other is looked at one value
        # at a time (_reason), which says which reason comes first.
        if not (
            len(xyz) == 3
            and t - t == 0.0  # finite: inf - inf and NaN - NaN are NaN
            and abs(xyz[0]) <= bound
            and abs(xyz[1]) <= bound
            and abs(xyz[2]) <= bound
        ):
            reason = self._reason(sample)
            if reason is not None:
                return self._drop(reason)
        newest = self.newest
        if now is None:
            ahead = newest + JUMP_S + 0.0
            early = False
        else:
            # Per reading (issue 29): _ahead_of_host's test spelt out here, not called, and max(d, 0.0) as
            # `0.0 if d < 0.0 else d` (no builtin call; the same for NaN and -0.0: d unless 0.0 > d).
            # Evaluated whether or not the test above needs it: it has no side effects.
            since = now - self._newest_at
            ahead = newest + JUMP_S + (0.0 if since < 0.0 else since)
            held = now - self._offset_at
            early = now - t < self._offset - CLOCK_RATE_SLACK * (0.0 if held < 0.0 else held) - JUMP_S
        if newest > -math.inf and (t < newest - JUMP_S or t > ahead or early):
            side = -1 if t < newest else 1
            if self._run_side != side or not self._run_last <= t <= self._run_last + JUMP_S:
                self._run_side, self._run_count, self._run_first = side, 0, t  # (re)start the run
            self._run_count += 1
            self._run_last = t
            if self._run_count >= REANCHOR_READINGS and t - self._run_first >= REANCHOR_SPAN_S:
                return self._reanchor(sample, Verdict.RESTART if side < 0 else Verdict.JUMP, now)
            return self._drop("past" if side < 0 else "future")
        self._run_side = 0
        if now is not None:
            offset = now - t
            if offset < self._window_least:
                self._window_least = offset
            if now - self._window_at >= SLOW_WINDOW_S:
                self._judge_rate(now)
            if self.slow:
                return self._drop("slow_clock")
        last = self._last.get(sample.kind)
        if last is not None:
            if t == last:
                return self._drop("duplicate")
            if t < last:
                return self._drop("out_of_order")
            if t < last + MIN_INTERVAL_S:
                return self._drop("burst")
        if newest == -math.inf:  # the stream's first reading
            self._anchor(t)
        self._accept(sample, now)
        return Verdict.ACCEPT

    def _ahead_of_host(self, t: float, now: float | None) -> bool:
        """Whether a reading stamped ``t`` (the phone's clock, s) that came at ``now`` (host s) is more
        than :data:`JUMP_S` ahead of the host's clock: its host-minus-stamp offset below the reference's
        (:data:`CLOCK_RATE_SLACK`). No host time, or no reference yet: not. :meth:`admit` spells this test
        out in line (a call per reading, issue 29); this is its reference, which
        ``tests/test_hunt9_k_admission_inline.py`` holds it to."""
        if now is None:
            return False
        slid = CLOCK_RATE_SLACK * max(now - self._offset_at, 0.0)
        return now - t < self._offset - slid - JUMP_S  # NaN (no reference): False

    def _judge_rate(self, now: float) -> None:
        """A window of :data:`SLOW_WINDOW_S` ended at ``now`` (host s): whether its least offset grew on the
        last window's by more than :data:`CLOCK_RATE_SLACK` of the host time between them — the stream's
        clock falling behind — and so whether, after :data:`SLOW_WINDOWS` such windows in a row, the clock
        runs slow (a window that did not grow ends it)."""
        least = self._window_least
        if self._window_at > -math.inf and least - self._last_least > CLOCK_RATE_SLACK * (
            now - self._window_at
        ):
            self._growths += 1
        else:
            self._growths = 0
        self.slow = self._growths >= SLOW_WINDOWS or (self.slow and self._growths > 0)
        self._last_least = least
        self._window_at = now
        self._window_least = math.inf

    def _reason(self, sample: SensorSample) -> str | None:
        """Why the reading cannot be one at all (its own values), or None."""
        if not math.isfinite(sample.t_s):
            return "bad_time"
        limit = self.limits.limit(sample.kind)
        for v in sample.xyz:
            if not math.isfinite(v):
                return "non_finite"
            if abs(v) > limit:
                return "out_of_range"
        return None

    def _drop(self, reason: str) -> Verdict:
        self.stats.dropped[reason] += 1
        self.last_reason = reason
        return Verdict.DROP

    def _accept(self, sample: SensorSample, now: float | None) -> None:
        if not self._confirmed:  # a later stamp of the anchor's clock confirms it (copies of it do not)
            self._confirmed = sample.t_s > self._anchor_t
            self._unconfirmed += not self._confirmed
        self.stats.accepted += 1
        self._last[sample.kind] = sample.t_s
        if sample.t_s > self.newest:
            self.newest = sample.t_s
            self._newest_at = -math.inf if now is None else now
        if now is not None:
            offset = now - sample.t_s
            if not offset >= self._offset:  # earlier than the reference (or none yet): it slides
                slid = self._offset - CLOCK_RATE_SLACK * max(now - self._offset_at, 0.0)
                self._offset = offset if not offset < slid else slid  # NaN slid: the offset itself
                self._offset_at = now

    def _reanchor(self, sample: SensorSample, verdict: Verdict, now: float | None) -> Verdict:
        """The stream's clock moved: forget the old one, take this reading as the first of the new. An
        anchor no reading confirmed was a stray, not a clock: counted dropped, answered ``STRAY``."""
        if not self._confirmed:
            self.stats.accepted -= self._unconfirmed
            self.last_reason = "future" if verdict is Verdict.RESTART else "past"  # where the strays lay
            self.stats.dropped[self.last_reason] += self._unconfirmed
            verdict = Verdict.STRAY
        elif verdict is Verdict.RESTART:
            self.stats.restarts += 1
        else:
            self.stats.jumps += 1
        self.anchored_from = self.newest
        self.newest = -math.inf
        self._offset = math.nan  # the new clock's reference: this reading's
        self._window_at, self._window_least, self._last_least = -math.inf, math.inf, math.nan
        self._growths = 0
        self.slow = False  # judged anew on the new clock
        self._last.clear()
        self._run_side = 0
        self._anchor(sample.t_s)
        self._accept(sample, now)
        return verdict

    def _anchor(self, t: float) -> None:
        """The stream's clock is anchored on a reading stamped ``t``: unconfirmed until a later one."""
        self._confirmed = False
        self._anchor_t = t
        self._unconfirmed = 0

    def as_dict(self) -> dict[str, object]:
        """For ``summary.json``."""
        s = self.stats
        return {"accepted": s.accepted, "dropped": dict(s.dropped), "restarts": s.restarts, "jumps": s.jumps}


def out_of_range(
    kind: SensorKind, t: NDArray[np.float64], xyz: NDArray[np.float64], limits: ReadingLimits
) -> NDArray[np.bool_]:
    """The readings of one sensor's whole stream (times ``t`` (N,) s, values ``xyz`` (N, 3)) that
    :meth:`PhoneGuard.admit` drops as ``out_of_range``: a finite stamp and finite values, one of them beyond
    the sensor's bound. A reading with a non-finite stamp or value is not among them: that is another
    reason, the merge's ``nan``. For a recording replayed in one batch, which takes no guard's path."""
    bound = min(limits.limit(kind), sys.float_info.max)
    finite = np.isfinite(t) & np.all(np.isfinite(xyz), axis=1)
    return finite & np.any(np.abs(xyz) > bound, axis=1)


__all__ = [
    "CLOCK_RATE_SLACK",
    "JUMP_S",
    "KINDS",
    "SLOW_WINDOWS",
    "SLOW_WINDOW_S",
    "AdmissionStats",
    "PhoneGuard",
    "ReadingLimits",
    "Verdict",
    "out_of_range",
]

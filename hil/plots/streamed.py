"""Series thinned as they are read: a run's figures from a telemetry of any length in bounded memory.

:class:`MinMaxStream` takes a run's rows a block at a time (:class:`hil.runtime.runlog.TelemetryBlocks`) and
keeps, for each column, at most :data:`MAX_POINTS` points: every point while there are no more, then the
minimum and the maximum of each of between ``MAX_POINTS / 4`` and ``MAX_POINTS / 2`` slices of equal rows
(a slice is a power of two rows long: when there are too many, neighbours are merged two by two). Every
spike stays visible, and memory holds the slices, not the run: a 10-hour run at 200 Hz is 7.2 million
rows, ~2 GB as floats.
"""

from __future__ import annotations

import numpy as np

from hil.runtime.runlog import JUMP_STEPS

PLOT_LIMIT = 1e300
"""Values beyond ± this are left out of the figures, as gaps (a figure's title counts them): no value a run
or a campaign writes is that large, but an edited file may say so, and matplotlib's tick locator loops for
ever on an axis near the largest float (2**1023), its transforms fail beyond (``LinAlgError: Singular
matrix`` for a battery at -1.7e308, rates from 1e308 to -1e308)."""

MAX_GAPS = 1000
"""Time gaps kept to draw at most (the widest ones); every one is counted."""

RECENT_STEPS = 64
"""Spacings between rows that a block's step is the median of, beside the block's own."""
MIN_STEPS = 8
"""Spacings seen at least before a gap is told (a run's first rows: its step is not known yet)."""

MAX_POINTS = 2000
"""Points per line at most: a longer series is drawn as the minimum and maximum of each of its slices
(every spike stays visible; a 10-minute real-time log at 200 Hz draws at most 2 000 points, not
120 000)."""


LO, HI, LO_I, HI_I, LO_T, HI_T = range(6)  # what a slice keeps per column: see MinMaxStream._v


class Gaps:
    """Where a run's rows stop for longer than its step, streamed: :meth:`add` the times of its rows taken
    (s, in order, a block at a time); a gap is two consecutive rows more than :data:`JUMP_STEPS` steps
    apart (the step: the median spacing of the block's rows and of the :data:`RECENT_STEPS` before them;
    until :data:`MIN_STEPS` spacings are seen there is none, and no gap) — a run that stalled, a file
    spliced. :attr:`count` counts them all; :meth:`spans`
    gives the widest :data:`MAX_GAPS` of them (start, end), in time order, for a figure to break its lines
    at (a line drawn across a gap looked like data the run never had)."""

    def __init__(self, jump: float = JUMP_STEPS, keep: int = MAX_GAPS) -> None:
        self.jump = jump
        self.keep = keep
        self.count = 0
        self.step: float | None = None
        self._last: float | None = None
        self._recent = np.zeros(0)  # the last RECENT_STEPS spacings between rows (s)
        self._spans = np.zeros((0, 2))

    def add(self, t: np.ndarray) -> None:
        if len(t) == 0:
            return
        times = t if self._last is None else np.concatenate([[self._last], t])
        self._last = float(t[-1])
        dt = np.diff(times)
        known = np.concatenate([self._recent, dt[dt > 0]])
        self._recent = known[-RECENT_STEPS:]
        if len(known) < MIN_STEPS:  # too few spacings seen to say what the run's step is
            return
        self.step = float(np.median(known))
        at = np.flatnonzero(dt > self.jump * self.step)
        if not len(at):
            return
        self.count += len(at)
        self._spans = np.concatenate([self._spans, np.column_stack([times[at], times[at + 1]])])
        if len(self._spans) > 2 * self.keep:
            self._spans = self._widest()

    def _widest(self) -> np.ndarray:
        spans = self._spans
        if len(spans) > self.keep:
            widest = np.argsort(spans[:, 1] - spans[:, 0], kind="stable")[-self.keep :]
            spans = spans[np.sort(widest)]
        return spans

    def spans(self) -> np.ndarray:
        """The widest :data:`MAX_GAPS` gaps, shape (n, 2): each one's last time before and first after (s)."""
        return self._widest()


class MinMaxStream:
    """The thinned series of ``width`` columns against a time (see the module docstring). :meth:`add` a
    block of rows (``t``: shape (n,), s; ``y``: shape (n, width)), then :meth:`series` gives each column's
    points. NaN is a gap: a slice with no number keeps its first row (NaN), as a gap to draw. A value
    beyond ±:data:`PLOT_LIMIT` is one too (counted per column: :attr:`off_scale`), and so is a time gap
    between rows (:class:`Gaps`, :attr:`gaps`): :meth:`series` breaks the line there."""

    def __init__(self, width: int, max_points: int = MAX_POINTS) -> None:
        self.width = width
        self.max_points = max_points
        self.rows = 0
        self.size = 0  # rows per slice; 0 while every row is kept (no more than max_points of them)
        self._raw_t: list[np.ndarray] = []
        self._raw_y: list[np.ndarray] = []
        # per slice × column: the lowest and highest value, their rows and times (see LO ... HI_T)
        self._v = np.zeros((6, max_points // 2 + 1, width))
        self._k = 0  # slices
        self._finite = np.zeros(width, dtype=bool)
        self.off_scale = np.zeros(width, dtype=np.int64)
        """Per column: the values left out as beyond ±:data:`PLOT_LIMIT`."""
        self.not_positive = np.zeros(width, dtype=np.int64)
        """Per column: the values ≤ 0 (a log scale has no place for them: its figure says how many)."""
        self.gaps = Gaps()

    def add(self, t: np.ndarray, y: np.ndarray) -> None:
        if len(t) == 0:
            return
        self._finite |= np.isfinite(y).any(axis=0)
        with np.errstate(invalid="ignore"):
            off = np.abs(y) > PLOT_LIMIT
        if off.any():
            self.off_scale += off.sum(axis=0)
            y = np.where(off, np.nan, y)
        with np.errstate(invalid="ignore"):
            self.not_positive += (y <= 0).sum(axis=0)
        self.gaps.add(t)
        if not self.size:
            self._raw_t.append(t)
            self._raw_y.append(y)
            if self.rows + len(t) <= self.max_points:
                self.rows += len(t)
                return
            t, y = np.concatenate(self._raw_t), np.concatenate(self._raw_y)
            self._raw_t, self._raw_y = [], []
            self.rows = 0
            self.size = 1
            while len(t) > self.size * (self.max_points // 2):
                self.size *= 2
        self._slices(t, y)

    @property
    def finite(self) -> np.ndarray:
        """Per column: whether any of its values is a number (shape (width,))."""
        return self._finite

    def peak(self) -> np.ndarray:
        """Per column: the largest magnitude of its values (NaN if none is a number; shape (width,))."""
        if self.size:
            values = np.abs(self._v[[LO, HI], : self._k].reshape(-1, self.width))
        elif self._raw_y:
            values = np.abs(np.concatenate(self._raw_y))
        else:
            return np.full(self.width, np.nan)
        most = np.max(np.where(np.isnan(values), -np.inf, values), axis=0)
        return np.where(self._finite, most, np.nan)

    def series(self, column: int) -> tuple[np.ndarray, np.ndarray]:
        """Column ``column``'s points: (t, y), in time order (a slice's lowest and highest, by row), a NaN
        in the middle of each time gap (:attr:`gaps`: the line broken there)."""
        t, y = self._points(column)
        spans = self.gaps.spans()
        if len(spans) and len(t):
            middle = spans[:, 0] / 2 + spans[:, 1] / 2
            at = np.searchsorted(t, middle)
            t, y = np.insert(t, at, middle), np.insert(y, at, np.nan)
        return t, y

    def _points(self, column: int) -> tuple[np.ndarray, np.ndarray]:
        if not self.size:
            if not self._raw_t:
                return np.zeros(0), np.zeros(0)
            return np.concatenate(self._raw_t), np.concatenate(self._raw_y)[:, column]
        v = self._v[:, : self._k, column]
        first_lo = v[LO_I] <= v[HI_I]
        t1, t2 = np.where(first_lo, v[LO_T], v[HI_T]), np.where(first_lo, v[HI_T], v[LO_T])
        y1, y2 = np.where(first_lo, v[LO], v[HI]), np.where(first_lo, v[HI], v[LO])
        keep = np.column_stack([np.ones(self._k, dtype=bool), v[LO_I] != v[HI_I]]).ravel()
        return np.column_stack([t1, t2]).ravel()[keep], np.column_stack([y1, y2]).ravel()[keep]

    def _slices(self, t: np.ndarray, y: np.ndarray) -> None:
        """Rows ``rows ..`` into their slices (merging slices two by two when there are too many)."""
        done = 0
        while done < len(t):
            row = self.rows + done
            n = min((row // self.size + 1) * self.size - row, len(t) - done)  # to the end of its slice
            self._into(row // self.size, t[done : done + n], y[done : done + n], row)
            done += n
            if self._k > self.max_points // 2:
                self._halve()
        self.rows += len(t)

    def _into(self, k: int, t: np.ndarray, y: np.ndarray, first_row: int) -> None:
        """Rows of slice ``k`` (the last one kept, or a new one after it), the first of them ``first_row``."""
        nan = np.isnan(y)
        lo_j = np.argmin(np.where(nan, np.inf, y), axis=0)  # the first lowest (a slice of NaN: its first)
        hi_j = np.argmax(np.where(nan, -np.inf, y), axis=0)
        cols = np.arange(self.width)
        new = np.stack([y[lo_j, cols], y[hi_j, cols], first_row + lo_j, first_row + hi_j, t[lo_j], t[hi_j]])
        if k < self._k:  # the last slice goes on: its extremes kept unless these rows beat them
            old = self._v[:, self._k - 1]
            lower, higher = _less(new[LO], old[LO]), _less(-new[HI], -old[HI])
            picks = np.stack([lower, higher, lower, higher, lower, higher])
            self._v[:, self._k - 1] = np.where(picks, new, old)
        else:
            self._v[:, self._k] = new
            self._k += 1

    def _halve(self) -> None:
        """Neighbouring slices merged two by two: slices twice as long, half as many."""
        n = self._k
        v = self._v[:, :n]
        a, b = v[:, 0 : n - 1 : 2], v[:, 1:n:2]  # pairs (0, 1), (2, 3), ...; an odd last one alone
        lower = _less(b[LO], a[LO])
        higher = _less(-b[HI], -a[HI])
        pairs = np.where(np.stack([lower, higher, lower, higher, lower, higher]), b, a)
        m = len(pairs[0])
        if n % 2:
            last = v[:, n - 1].copy()
            self._v[:, :m] = pairs
            self._v[:, m] = last
            self._k = m + 1
        else:
            self._v[:, :m] = pairs
            self._k = m
        self.size *= 2


def _less(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``x < y``, a NaN above every number (a number beats a NaN; of two NaNs the earlier, ``y``, stays)."""
    return (x < y) | (np.isnan(y) & ~np.isnan(x))

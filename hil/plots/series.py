"""Long series made drawable: a min/max envelope per pixel column, and angles without wrap-around lines.

A replay of a 700 s log at 100 Hz has 70 000 points per line; drawn as they are, an 8 in figure shows a
solid band (each of ~700 pixel columns crossed a hundred times) and matplotlib spends most of the figure's
time on them. :func:`envelope` keeps, per bin of :data:`MAX_BINS`, the mean (the line) and the minimum and
maximum (a shaded band), so every excursion is still seen and its extremes are exact. :func:`break_wraps`
cuts an angle's line where it wraps (yaw from +180° to −180°) instead of drawing a vertical line across the
axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

MAX_BINS = 1_500
"""Bins across the time axis (about two per pixel column of an 8 in figure at 110 dpi)."""
PIXEL_COLUMNS = 700
"""Pixel columns across a figure's time axis, about (the axes of a 10 in figure at 110 dpi, less the
margins and the legend): a stretch of a line narrower than one of them is drawn as nothing visible."""


@dataclass(frozen=True)
class Envelope:
    """One series in bins: ``t`` (B,) s, the bin's centre; ``mean``, ``low``, ``high`` (B,) in the
    series' unit. Bins with no finite value are NaN (a gap stays a gap); an angle's envelope has a NaN
    row besides wherever its line is cut (B counts those too)."""

    t: NDArray[np.float64]
    mean: NDArray[np.float64]
    low: NDArray[np.float64]
    high: NDArray[np.float64]


def envelope(
    t: NDArray[np.float64], y: NDArray[np.float64], bins: int = MAX_BINS, period: float | None = None
) -> Envelope | None:
    """``y`` (N,) against ``t`` (N,) s in ``bins`` equal spans of time, or None when ``y`` has no more
    points than two per bin (then it is drawn as it is). With ``period`` (an angle's, e.g. 360 deg), a bin
    in which the series wraps around is left empty, and two neighbouring bins whose means are more than
    half a turn apart are cut apart: the line is never drawn across the axes, nor the wrong way round."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if len(t) <= 2 * bins or not np.isfinite(t).all() or t[-1] <= t[0]:
        return None
    edges = np.linspace(t[0], t[-1], bins + 1)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
    finite = np.isfinite(y)
    count = np.bincount(index[finite], minlength=bins)
    total = np.bincount(index[finite], weights=y[finite], minlength=bins)
    low = np.full(bins, np.inf)
    high = np.full(bins, -np.inf)
    np.minimum.at(low, index[finite], y[finite])
    np.maximum.at(high, index[finite], y[finite])
    empty = count == 0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    if period is not None:
        wrapped = np.flatnonzero(np.abs(np.diff(y)) > period / 2) + 1
        empty |= np.bincount(index[wrapped], minlength=bins) > 0
    mean[empty] = low[empty] = high[empty] = np.nan
    centres = 0.5 * (edges[:-1] + edges[1:])
    if period is not None:
        # Two neighbouring bins whose means are more than half a turn apart without a wrap between them:
        # the angle turned faster than half a turn a bin, and a line between them would read as turning
        # the other way. Cut it there (a NaN row at the later bin's time), as at a wrap.
        cuts = np.flatnonzero(np.abs(np.diff(mean)) > period / 2) + 1
        if cuts.size:
            centres = np.insert(centres, cuts, centres[cuts])
            mean, low, high = (np.insert(a, cuts, np.nan) for a in (mean, low, high))
    return Envelope(centres, mean, low, high)


def lone_points(
    t: NDArray[np.float64], y: NDArray[np.float64], columns: int = PIXEL_COLUMNS
) -> NDArray[np.bool_]:
    """Where ``y`` (N,) against ``t`` (N,) s, in time order, has a number its line cannot show: each
    stretch of consecutive numbers (between NaN gaps, or the ends) that spans less time than one of
    ``columns`` pixel columns of the time axis (the series' first to last finite time). A line is drawn
    between two points only, so a reading alone between gaps (the one row a board sent between silences,
    a run of one row) drew nothing, and a burst of rows after a long gap (a file spliced 10⁶ s later) a
    line shorter than a pixel: measured values shown as no data. These points are to be drawn as dots."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    finite = np.isfinite(y) & np.isfinite(t)
    if not finite.any():
        return finite
    pixel = (t[finite].max() - t[finite].min()) / columns  # s; 0 when every number is at one time
    begins = finite & ~np.concatenate([[False], finite[:-1]])
    ends = finite & ~np.concatenate([finite[1:], [False]])
    narrow = t[ends] - t[begins] <= pixel  # per stretch
    stretch = np.maximum(np.cumsum(begins) - 1, 0)  # each point's stretch (before the first: none, masked)
    return finite & narrow[stretch]


def break_wraps(y: NDArray[np.float64], period: float = 360.0) -> NDArray[np.float64]:
    """``y`` (N,) with NaN put between two neighbours more than half a ``period`` apart (a wrap-around:
    the line is cut there instead of crossing the axes); (N + wraps,) values, for ``t`` from
    :func:`wrap_times`."""
    y = np.asarray(y, dtype=float)
    jumps = np.flatnonzero(np.abs(np.diff(y)) > period / 2) + 1
    return np.insert(y, jumps, np.nan)


def wrap_times(t: NDArray[np.float64], y: NDArray[np.float64], period: float = 360.0) -> NDArray[np.float64]:
    """The times for :func:`break_wraps`'s values: each cut at the time of the sample after it."""
    y = np.asarray(y, dtype=float)
    jumps = np.flatnonzero(np.abs(np.diff(y)) > period / 2) + 1
    return np.insert(np.asarray(t, dtype=float), jumps, np.asarray(t, dtype=float)[jumps])

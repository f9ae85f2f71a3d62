"""Is the gyroscope in rad/s? A plausibility check of a log's gyroscope unit against its accelerometer.

A gyroscope column without a unit is read as SI (rad/s, :mod:`hil.logs.columns`); one written in deg/s
with no unit in its header (a script's re-export) is then read 57.3 times too fast, and the attitude comes
out wrong by tens of degrees with no error. The accelerometer tells: over a second of motion the direction
of gravity it measures turns by about the angle the phone turned (a rotation about the vertical leaves it
where it is, so by less), while a gyroscope read 57.3 times too fast integrates to far more.

:func:`gyro_turn_ratio` is the median, over windows of :data:`WINDOW_S` in which the gravity direction
turned by at least :data:`MIN_SWEEP_DEG`, of the angle the gyroscope integrates (the norm of its integral)
over the angle the gravity direction (the mean accelerometer direction over the window's first and last
:data:`EDGE_S`) turned. :data:`DEG_S_RATIO` is the ratio above which the gyroscope is suspected to read in
deg/s: the check warns (naming the log and the unit), it never refuses a log.

How :data:`DEG_S_RATIO` was chosen (``tests/test_replay_gyro_units.py`` repeats it on every recording):
the ratio of every recording in ``../shared/data`` — the 14 tyrex Nexus 5 trials (calibrated gyroscope),
the 8 BROAD trials, the Sensor Logger export — lies in 0.31-3.22 (largest: BROAD's fast combined trial,
3.22; then tyrex Swinging, 3.06); the same recordings with their gyroscope written in deg/s (57.3 times
each) lie in 17.8-184 (smallest: the Sensor Logger export, 17.75). The threshold is the geometric mean of
the largest real ratio and the smallest deg/s one, rounded down: sqrt(3.22 x 17.75) = 7.56 -> 7.5, a
factor of 2.3 above every real recording and 2.4 below every deg/s one.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.estimation.sensors import SensorKind, SensorLog
from hil.logs.file_names import sensor_files_where

Array = NDArray[np.float64]

WINDOW_S = 1.0
"""s: the windows of motion compared (overlapping by half)."""
EDGE_S = 0.1
"""s: the gravity direction at each end of a window is the accelerometer's mean direction over this."""
MIN_SWEEP_DEG = 10.0
"""A window whose gravity direction turned by less is no motion to compare (noise, or a turn about the
vertical that gravity does not see)."""
MIN_WINDOWS = 5
"""Fewer windows of motion than this: not checked (a log lying still says nothing of the unit)."""
DEG_S_RATIO = 7.5
"""Above this median ratio the gyroscope is suspected to read in deg/s (the procedure: module docstring)."""


MAX_STEP_S = 1e6
"""s: the longest step of a clock :func:`_cumulative` integrates over whole. A window (1 s) takes at most a
second's worth of any step, so a longer step changes no window's figure; capped, a stray row at 1e160 or
1e308 s makes no overflow (a reading times 1e308 s is infinite)."""


def _cumulative(t: Array, y: Array) -> Array:
    """The running trapezoid integral of ``y`` (N, k) over ``t`` (N,, increasing), starting at 0; a step of
    ``t`` longer than :data:`MAX_STEP_S` counted as that long."""
    steps = 0.5 * (y[1:] + y[:-1]) * np.minimum(np.diff(t), MAX_STEP_S)[:, None]
    return np.vstack([np.zeros((1, y.shape[1])), np.cumsum(steps, axis=0)])


def _window_starts(gt: Array, start: float, end: float) -> Array:
    """The windows' starts: the points of the half-window grid from ``start`` whose half-window holds a
    gyroscope sample (times ``gt``, increasing), and whose window ends by ``end``. On a log sampled
    throughout that is every point of the grid; across a gap in the log, none — so there are never more
    windows than samples, however far apart a log's times are (one stray row 1e8 s on made the grid 2e8
    windows: 24 GB; at 1e308, no grid at all)."""
    half = WINDOW_S / 2
    with np.errstate(over="ignore", invalid="ignore"):
        cells = np.unique(np.floor((gt[(gt >= start) & (gt <= end)] - start) / half))
        t0 = start + cells * half
    return t0[np.isfinite(t0) & (t0 < end - WINDOW_S)]


def _increasing(t: Array, y: Array) -> tuple[Array, Array]:
    """``t`` (s) and its readings ``y`` in time order, a repeated time kept once. Dropping each sample not
    later than the one before it kept a stray far ahead (one row at 1e160 s) among the rest: the integrals
    were interpolated over a clock that went back, and overflowed."""
    order = np.argsort(t, kind="stable")
    t, y = t[order], y[order]
    keep = np.diff(t, prepend=-np.inf) > 0
    return t[keep], y[keep]


def gyro_turn_ratio(log: SensorLog) -> tuple[float, int]:
    """(median ratio, windows of motion): the angle the gyroscope integrates over the angle the gravity
    direction turns, over windows of motion (module docstring); (nan, windows) when there are fewer than
    :data:`MIN_WINDOWS` of them."""
    gyr, acc = log.streams[SensorKind.GYR], log.streams[SensorKind.ACC]
    g_ok = np.isfinite(gyr.t) & np.all(np.isfinite(gyr.xyz), axis=1)
    a_norm = np.linalg.norm(acc.xyz, axis=1)
    a_ok = np.isfinite(acc.t) & np.isfinite(a_norm) & (a_norm > 0)
    gt, gw = gyr.t[g_ok], gyr.xyz[g_ok]
    at, au = acc.t[a_ok], acc.xyz[a_ok] / a_norm[a_ok, None]
    if len(gt) < 3 or len(at) < 3:
        return math.nan, 0
    gt, gw = _increasing(gt, gw)
    at, au = _increasing(at, au)
    if len(gt) < 3 or len(at) < 3:
        return math.nan, 0
    turned = _cumulative(gt, gw)
    pointed = _cumulative(at, au)
    t0 = _window_starts(gt, max(gt[0], at[0]), min(gt[-1], at[-1]))
    if not len(t0):
        return math.nan, 0
    t1 = t0 + WINDOW_S

    def integral(t: Array, c: Array, a: Array, b: Array) -> Array:
        return np.column_stack([np.interp(b, t, c[:, i]) - np.interp(a, t, c[:, i]) for i in range(3)])

    gyro_deg = np.degrees(np.linalg.norm(integral(gt, turned, t0, t1), axis=1))
    first = integral(at, pointed, t0, t0 + EDGE_S)
    last = integral(at, pointed, t1 - EDGE_S, t1)
    with np.errstate(invalid="ignore", divide="ignore"):  # a window with no accelerometer sample: NaN
        cos = np.sum(first * last, axis=1) / (np.linalg.norm(first, axis=1) * np.linalg.norm(last, axis=1))
        sweep_deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        moving = np.isfinite(sweep_deg) & (sweep_deg >= MIN_SWEEP_DEG) & np.isfinite(gyro_deg)
    n = int(moving.sum())
    if n < MIN_WINDOWS:
        return math.nan, n
    return float(np.median(gyro_deg[moving] / sweep_deg[moving])), n


def gyro_unit_warning(log: SensorLog) -> str | None:
    """A warning when the log's gyroscope seems to read in deg/s (:data:`DEG_S_RATIO`), naming the log; None
    when it is plausibly rad/s or cannot be told (too little motion)."""
    ratio, windows = gyro_turn_ratio(log)
    if not ratio > DEG_S_RATIO:
        return None
    where = sensor_files_where(log, "[Gg]yro")
    return (
        f"{where}: its gyroscope turns {ratio:.3g} times as far as gravity does over {windows} one-second "
        f"windows of motion (a gyroscope in rad/s: 0.3-3.2 over the shared recordings; {DEG_S_RATIO:g} the "
        "bound): it seems to read in deg/s, not rad/s, with no unit in its header (read as SI); the "
        "attitude is wrong if so: convert the column to rad/s, or name its unit in the header, e.g. "
        "'x (deg/s)'"
    )

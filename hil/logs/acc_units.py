"""Is the accelerometer in m/s²? A plausibility check of a log's accelerometer unit by its magnitude.

An accelerometer column without a unit is read as SI (m/s², :mod:`hil.logs.columns`); one written in g
(Sensor Logger on iOS without "Standardise Units & Frames", a script's re-export) is then read 9.81
times too small, with no error. Gravity tells: a phone's accelerometer measures gravity plus its own
acceleration, so the median of its norm over a recording is about 9.81 m/s² however it moves (a runner's
bounces lift it, never divide it by 9.81); in g, about 1.

:func:`acc_norm_median` is that median. :data:`G_NORM_M_S2` is the median below which the accelerometer is
suspected to read in g (or to be gravity-free, which reads as small): the check warns (naming the log and
the unit), it never refuses a log nor converts it — a unit the header states (``x (g)``) is converted by
the reader, as is Sensor Logger's ``AccelerometerUncalibrated.csv`` whose median norm is about 1 (iOS
writes that file in g).

How :data:`G_NORM_M_S2` was chosen (``tests/test_replay_acc_units.py`` repeats it on every
recording): the median norm of every recording in ``../shared/data`` — the 14 tyrex Nexus 5 trials, the
8 BROAD trials, the Sensor Logger export — lies in 9.62-15.66 m/s² (smallest: tyrex Dist_Texting, 9.62;
largest: tyrex NoDist_RunningHand, 15.66); the same recordings with their accelerometer written in g lie
in 0.981-1.597. The threshold is the geometric mean of the smallest real median and the largest g one,
rounded down: sqrt(9.62 x 1.597) = 3.92 -> 3.9 m/s², a factor of 2.47 below every real recording and
2.44 above every one in g.
"""

from __future__ import annotations

import math

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog
from hil.logs.file_names import sensor_files_where

G_NORM_M_S2 = 3.9
"""m/s²: below this median norm the accelerometer is suspected to read in g (the procedure: module
docstring)."""
MIN_SAMPLES = 10
"""Fewer finite samples than this: not checked."""


def acc_norm_median(log: SensorLog) -> float:
    """The median norm of the log's accelerometer readings (m/s² as read), over its finite samples; NaN
    with fewer than :data:`MIN_SAMPLES` of them."""
    acc = log.streams.get(SensorKind.ACC)
    if acc is None:
        return math.nan
    norm = np.linalg.norm(acc.xyz, axis=1)
    norm = norm[np.isfinite(norm) & np.isfinite(acc.t)]
    return float(np.median(norm)) if len(norm) >= MIN_SAMPLES else math.nan


def acc_unit_warning(log: SensorLog) -> str | None:
    """A warning when the log's accelerometer seems to read in g (:data:`G_NORM_M_S2`), naming the log and
    its accelerometer file; None when it is plausibly m/s² or cannot be told."""
    norm = acc_norm_median(log)
    if not norm < G_NORM_M_S2:
        return None
    where = sensor_files_where(log, "[Aa]ccel")
    return (
        f"{where}: its accelerometer's median norm is {norm:.3g} m/s^2 (gravity alone is 9.81; the shared "
        f"recordings 9.6-15.7; {G_NORM_M_S2:g} the bound): it seems to read in g, not m/s^2, with no unit "
        "in its header (read as SI), or to be gravity-free; rest detection and the accelerometer's checks "
        "are wrong if so: convert the column to m/s^2, or name its unit in the header, e.g. 'x (g)'"
    )

"""Per-run figures of merit of a Monte Carlo run, and its decimated error traces, from the run's per-tick
trace (:class:`hil.runtime.RunTrace` as arrays: ``t`` from the slew's start, ``point_err_deg``,
``track_err_deg``, ``est_err_deg``, ``gimbal_rate``, ``delta``; one value per control tick).

The names and definitions follow ``hil run``'s ``summary.json`` where both have a figure, so a campaign
and a single run are read the same way. Times are from the slew's start; errors are true errors (the
simulation knows the truth).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

Trace = Mapping[str, NDArray[np.float64]]
"""A run's trace as arrays (:meth:`hil.runtime.RunTrace.arrays`)."""

METRICS: tuple[str, ...] = (
    "settle_s",
    "final_error_deg",
    "peak_error_deg",
    "peak_tracking_deg",
    "peak_gimbal_rate",
    "min_delta",
    "estimator_rmse_deg",
    "failsafe_events",
)
"""The results' metric columns, in order:

- ``settle_s``: first time after which the pointing error stays within the scenario's ``settle_deg``
  (inf: never within the run);
- ``final_error_deg``: pointing error to the target, mean over the run's last second;
- ``peak_error_deg``: largest pointing error to the target (the slew angle, or more on an overshoot);
- ``peak_tracking_deg``: largest error to the moving reference (how well the slew was followed);
- ``peak_gimbal_rate``: largest |gimbal rate| of any unit (rad/s), over the ticks with a live board;
- ``min_delta``: smallest singularity measure δ (0 at a CMG singularity or with the rotors stopped; 1.19 for
  the pyramid at rest), over the ticks with a live board;
- ``estimator_rmse_deg``: RMS of the estimator's attitude error over slew and hold;
- ``failsafe_events``: how many times the board's link watchdog fired.
"""

TRACES: tuple[str, ...] = ("error_deg", "estimate_error_deg")
"""What a run's trace records, each decimated to the campaign's trace rate: pointing error to the target
and the estimator's attitude error (deg)."""


TRACE_FIELDS = {"error_deg": "point_err_deg", "estimate_error_deg": "est_err_deg"}
"""Which field of the run's trace each stored trace is."""


def settle_time(t: NDArray[np.float64], error_deg: NDArray[np.float64], tolerance_deg: float) -> float:
    """The first time after which ``error_deg`` stays within ``tolerance_deg`` (inf: never)."""
    outside = np.nonzero(~(error_deg <= tolerance_deg))[0]
    if len(outside) == 0:
        return float(t[0])
    if outside[-1] == len(t) - 1:
        return math.inf
    return float(t[outside[-1] + 1])


def run_metrics(trace: Trace, settle_deg: float, failsafe_events: int) -> dict[str, float]:
    """The :data:`METRICS` of one run from its ``trace`` and its board's ``failsafe_events``."""
    t, err = trace["t"], trace["point_err_deg"]
    if len(t) == 0:
        raise ValueError("the run's trace is empty (the slew never started)")
    last = t >= t[-1] - 1.0
    return {
        "settle_s": settle_time(t, err, settle_deg),
        "final_error_deg": float(np.mean(err[last])),
        "peak_error_deg": float(np.max(err)),
        "peak_tracking_deg": float(np.nanmax(trace["track_err_deg"])),  # NaN at the slew's first tick
        "peak_gimbal_rate": float(np.nanmax(trace["gimbal_rate"])),  # NaN: no live board at that tick
        "min_delta": float(np.nanmin(trace["delta"])),
        "estimator_rmse_deg": float(np.sqrt(np.mean(np.square(trace["est_err_deg"])))),
        "failsafe_events": float(failsafe_events),
    }


def trace_length(duration_s: float, trace_hz: float) -> int:
    """Samples in a trace of a run of ``duration_s`` at ``trace_hz``."""
    return int(math.ceil(duration_s * trace_hz - 1e-9))


def decimated_trace(trace: Trace, trace_hz: float, samples: int) -> NDArray[np.float32]:
    """(len(TRACES), samples) float32: each trace sampled every ``1/trace_hz`` s from the slew's start
    (the control tick at or just before each time; NaN past the trace's end)."""
    out = np.full((len(TRACES), samples), np.nan, dtype=np.float32)
    t = trace["t"]
    times = np.arange(samples) / trace_hz
    idx = np.searchsorted(t, times + 1e-9, side="right") - 1
    ok = (idx >= 0) & (times <= t[-1] + 1e-9)
    for row, name in enumerate(TRACES):
        out[row, ok] = trace[TRACE_FIELDS[name]][idx[ok]]
    return out

"""Per-run figures of merit of a Monte Carlo run, and its decimated error traces.

The names and definitions follow ``hil run``'s ``summary.json`` where both have a figure, so a campaign
and a single run are read the same way. Times are from the slew's start; errors are true errors (the
simulation knows the truth).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.simulation.closed_loop import ClosedLoopLog

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
- ``peak_gimbal_rate``: largest |gimbal rate| of any unit (rad/s);
- ``min_delta``: smallest singularity measure δ (0 at a CMG singularity; 1.19 for the pyramid at rest);
- ``estimator_rmse_deg``: RMS of the estimator's attitude error over slew and hold;
- ``failsafe_events``: how many times the board's link watchdog fired.
"""

TRACES: tuple[str, ...] = ("error_deg", "estimate_error_deg")
"""What a run's trace records, each decimated to the campaign's trace rate: pointing error to the target
and the estimator's attitude error (deg)."""


def run_metrics(log: ClosedLoopLog, settle_deg: float) -> dict[str, float]:
    """The :data:`METRICS` of one run."""
    figures = log.summary(settle_deg)
    return {
        "settle_s": figures["settle_time_s"],
        "final_error_deg": figures["final_error_deg"],
        "peak_error_deg": float(np.max(log.error_deg)),
        "peak_tracking_deg": float(np.max(log.tracking_deg)),
        "peak_gimbal_rate": figures["peak_gimbal_rate"],
        "min_delta": figures["min_delta"],
        "estimator_rmse_deg": float(np.sqrt(np.mean(np.square(log.estimate_error_deg)))),
        "failsafe_events": float(log.failsafe_events),
    }


def trace_length(duration_s: float, trace_hz: float) -> int:
    """Samples in a trace of a run of ``duration_s`` at ``trace_hz``."""
    return int(math.ceil(duration_s * trace_hz - 1e-9))


def decimated_trace(log: ClosedLoopLog, trace_hz: float, samples: int) -> NDArray[np.float32]:
    """(len(TRACES), samples) float32: each trace sampled every ``1/trace_hz`` s from the slew's start
    (the control tick at or just before each time; NaN past the log's end)."""
    out = np.full((len(TRACES), samples), np.nan, dtype=np.float32)
    times = np.arange(samples) / trace_hz
    idx = np.searchsorted(log.t, times + 1e-9, side="right") - 1
    ok = (idx >= 0) & (times <= log.t[-1] + 1e-9)
    for row, name in enumerate(TRACES):
        out[row, ok] = getattr(log, name)[idx[ok]]
    return out

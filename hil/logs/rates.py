"""A sensor whose sample rate drops part-way through a log: found, counted and said, never estimated through
in silence.

A phone that throttles a sensor (a screen switched off, the app sent to the background, a power saver)
goes on writing rows at a fraction of its rate: 100 Hz for half the log, 5 Hz after. Every check of a
log's rate took the median step over the whole log, which the fast half sets, and the slow half passed
unnoticed: its steps are shorter than a gap (``max_gap_s``: no split), the estimator's nominal period
(:class:`hil.estimation.interface.Site`'s ``sample_period_s``, the fastest sensor's median step) stayed
the fast one's — an estimator with a fixed period (VQF) integrated each 0.2 s step as 0.01 s (it now
sub-steps them: :mod:`hil.estimation.vqf_adapter`) — and the replay said nothing.

:func:`rate_drops` judges each sensor's rate locally: the mean step over :data:`RATE_RUN` consecutive
steps (one late or missing sample moves it little; a sustained drop moves it all) against the sensor's
own rate where it samples fastest (the :data:`FAST_PERCENTILE` th percentile of those mean steps: not the
median, which a slow stretch holding most of the samples would set — 50 Hz for 10 s, 16 Hz for 50 s is a
16 Hz log by its median). Steps in a run more than :data:`RATE_DROP_FACTOR` times slower are counted
(steps and the seconds they span); a sensor with :data:`RATE_DROP_WARNED_S` or more of them is reported
(:class:`RateDrop`; :func:`hil.logs.replay.rate_drop_warning` says it). A jump longer than ``max_gap_s``
is a gap, split and said on its own, and is no slow step here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog

RATE_RUN = 9
"""Consecutive steps of one sensor over which its local rate is judged (their mean step): one late or lost
sample among them moves it by an 1/9 of a step, a sustained drop by all of it."""
FAST_PERCENTILE = 10.0
"""%: the percentile of a sensor's runs' mean steps taken for its own rate (its fastest stretches; a few
runs of a burst faster than it stay below it)."""
RATE_DROP_FACTOR = 1.5
"""A run of steps whose mean step is more than this many times the sensor's own (:data:`FAST_PERCENTILE`)
is slow (100 Hz falling to 66 Hz or below; phone jitter and a lone lost sample stay well under)."""
RATE_DROP_WARNED_S = 1.0
"""s: a sensor slow for this long in all (the seconds its slow steps span) is reported; a shorter
stretch is a hiccup, which the merge's own gap flags already count."""


@dataclass(frozen=True)
class RateDrop:
    """Where one sensor's rate fell below its own (see the module docstring).

    ``steps``: its sample steps in slow runs; ``seconds``: the time they span (s); ``first_s``: log time
    (s) at which the first slow run begins; ``rate_hz``: the sensor's own rate, where it samples fastest
    (1 / the :data:`FAST_PERCENTILE` th percentile of its runs' mean steps); ``slowest_hz``: its slowest
    local rate (1 / the longest mean step of a run)."""

    kind: SensorKind
    steps: int
    seconds: float
    first_s: float
    rate_hz: float
    slowest_hz: float

    def as_dict(self) -> dict[str, float | int]:
        """For ``summary.json`` (``rate_drops``, keyed by the sensor's label)."""
        return {
            "slow_steps": self.steps,
            "slow_s": round(self.seconds, 4),
            "first_slow_s": round(self.first_s, 4),
            "rate_hz": round(self.rate_hz, 4),
            "slowest_hz": round(self.slowest_hz, 4),
        }


def rate_drops(log: SensorLog, max_gap_s: float) -> list[RateDrop]:
    """Each sensor of ``log`` whose rate drops for :data:`RATE_DROP_WARNED_S` or more below its own
    rate (steps up to ``max_gap_s`` long, s; a longer one is a gap, said elsewhere), in
    :class:`SensorKind` order."""
    drops = []
    for kind in sorted(log.streams):
        drop = _rate_drop(kind, log.streams[kind].t, max_gap_s)
        if drop is not None and drop.seconds >= RATE_DROP_WARNED_S:
            drops.append(drop)
    return drops


def _rate_drop(kind: SensorKind, times: np.ndarray, max_gap_s: float) -> RateDrop | None:
    """One sensor's slow runs (``times``: its sample times, s, as read), or None when it has none or too
    few steps to judge (fewer than :data:`RATE_RUN`)."""
    t = np.unique(times[np.isfinite(times)])  # sorted; a repeated time is the merge's to drop and count
    dt = np.diff(t)
    if dt.size < RATE_RUN:
        return None
    within = np.where(dt <= max_gap_s, dt, np.nan)  # a gap is split and said on its own: no slow step
    typical = float(np.nanmedian(within)) if np.isfinite(within).any() else math.nan
    if not typical > 0:
        return None
    within = np.where(np.isnan(within), typical, within)
    # the mean step of the run of RATE_RUN steps centred on each step (clipped at the ends)
    sums = np.concatenate([[0.0], np.cumsum(within)])
    starts = np.clip(np.arange(dt.size) - RATE_RUN // 2, 0, dt.size - RATE_RUN)
    mean_step = (sums[starts + RATE_RUN] - sums[starts]) / RATE_RUN
    own = float(np.percentile(mean_step, FAST_PERCENTILE))
    slow = (mean_step > RATE_DROP_FACTOR * own) & (dt <= max_gap_s)
    if not slow.any():
        return None
    return RateDrop(
        kind,
        steps=int(np.count_nonzero(slow)),
        seconds=float(dt[slow].sum()),
        first_s=float(t[int(np.argmax(slow))]),
        rate_hz=1.0 / own,
        slowest_hz=1.0 / float(mean_step.max()),
    )

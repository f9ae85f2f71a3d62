"""How the tuned preset's longest estimator step (``EstimatorParams.max_step_s``: a longer step is split into
sub-steps, the gyro interpolated, the measurement held) was chosen: every other setting fixed at the preset,
each candidate run on every shared trial with ground truth at its own rate (199 Hz smartphone, 286 Hz BROAD)
and thinned to 100, 50 and 25 Hz (every k-th sample of each sensor: a phone app set to a lower rate), VQF on
the same steps in the same run. Objective, the tuning's on the total RMSE with each family at each rate a
group: ``J = max over groups of mean RMSE(ours) / mean RMSE(VQF)``; the least J among the candidates that
split no step of a phone at its usual rate (:data:`USUAL_RATE_HZ`: shorter ones sub-step every sample there,
doubling the per-sample cost of the host's 200 Hz phone for ~1 % on J). Why it matters: the estimator's error
dynamics (m, D) were tuned at 3.5-5 ms steps; at 40 ms, ``h D / 2`` exceeds ``m`` and the discrete dynamics
turn oscillatory — BROAD at 25 Hz was 1.5x VQF's error. Run: ``python -m bench.estimator_rates [candidates,
s]``; docs/estimator.md, "Slower phones", holds the run that chose it."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from bench.bench_estimator import Trial, _trial_of, load_trials
from bench.estimator_choice import choose
from hil.estimation.filter import FilterConfig
from hil.estimation.sensors import SensorLog, SensorStream

RATES_HZ = (None, 100.0, 50.0, 25.0)
"""The rates the trials run at: their own (None), then thinned."""
CANDIDATES = (0.05, 0.02, 0.01, 0.0075, 0.006, 0.005, 0.004)
"""Longest steps tried (s); 0.05 is the estimator's default."""
USUAL_RATE_HZ = 167.0
"""A phone's usual rate (Hz), the shared smartphone trials' 199 Hz and the host's 200 Hz with jitter: a
candidate shorter than its period is not chosen."""


def thinned(trial: Trial, rate_hz: float | None) -> Trial:
    """``trial`` with every sensor thinned to about ``rate_hz`` (every k-th sample; None: as recorded)."""
    if rate_hz is None:
        return trial
    log = trial.log
    streams = {}
    for kind, stream in log.streams.items():
        period = float(np.median(np.diff(stream.t)))
        k = max(1, round(1.0 / rate_hz / period))
        streams[kind] = SensorStream(kind, stream.t[::k], stream.xyz[::k])
    thin = SensorLog(streams, log.source, log.format, log.truth, log.notes, log.dropped)
    return _trial_of(thin, trial.path, f"{trial.name} at {rate_hz:g} Hz", trial.group)


def config(max_step_s: float) -> FilterConfig:
    base = FilterConfig.tuned()
    return dataclasses.replace(base, params=dataclasses.replace(base.params, max_step_s=max_step_s))


def table(candidates: tuple[float, ...]) -> str:
    """One row per candidate: each group's mean total RMSE (degrees) and ratio to VQF's, and J."""
    runs = [
        (thinned(t, r), f"{t.family} {'own rate' if r is None else f'{r:g} Hz'}")
        for t in load_trials(cropped=False)
        for r in RATES_HZ
    ]
    return choose("max_step_s", runs, candidates, config, lambda s: s >= 1.0 / USUAL_RATE_HZ)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("candidates", nargs="*", type=float, default=list(CANDIDATES), help="longest steps, s")
    print(table(tuple(ap.parse_args(argv).candidates)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

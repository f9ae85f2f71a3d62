"""A recording that starts mid-motion (a phone log cut anywhere, a replay started late): the measured
restart takes one step's readings, its accelerometer there tens of degrees off gravity and the field's
horizontal part, taken against that wrong vertical, up to half a turn off. The estimator, a smoothing
filter, climbed out of such a start in 20-60 s (BROAD's fast translation cut at half its length: 95° RMSE
over its first 30 s). The tuned preset now settles (``FilterConfig.settle_s``): it restarts from the
means of the readings in the strapdown frame until they have averaged the motion out.

On real recordings with ground truth (BROAD's fast translation and fast combined motion, a smartphone
carried running), each cut to start at moments drawn across its length."""

from __future__ import annotations

import numpy as np
import pytest

from hil import so3
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.metrics import AttitudeErrors, resample_quats
from hil.estimation.multirate import MergePolicy, first_full_step, merge
from hil.estimation.sensors import SensorKind, SensorLog
from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import ConfigError

TRIALS = [
    "broad/15_undisturbed_fast_translation_A.mat",
    "broad/21_undisturbed_fast_combined.mat",
    "tyrex-nexus5/Guillaume_Nexus5_NoDist_RunningHand",
]
FIRST_S = 30.0  # the start scored: what a far start costs
CUTS = 3  # moments drawn per trial


def first_seconds_rmse(log: SensorLog, settle_s: float) -> float:
    """RMSE (degrees) of the tuned preset's total error over the evaluated samples of the log's first
    :data:`FIRST_S` seconds."""
    steps, _ = merge(log.streams, MergePolicy(driver=SensorKind.GYR))
    steps = steps.rows(first_full_step(steps))
    quat = AttitudeFilter(FilterConfig.tuned(settle_s=settle_s)).run(steps).quat
    truth = log.truth
    assert truth is not None
    finite = np.all(np.isfinite(truth.R.reshape(len(truth), 9)), axis=1)
    q_ref = np.full((len(truth), 4), np.nan)
    q_ref[finite] = so3.matrix_to_quat(truth.R[finite])
    total = AttitudeErrors.from_quats(resample_quats(steps.t, quat, truth.t), q_ref).total
    mask = finite & (truth.t < log.start + FIRST_S) & np.isfinite(total)
    if truth.evaluate is not None:
        mask &= np.asarray(truth.evaluate)
    assert mask.sum() > 100, "the cut left nothing scored: the test does not test"
    return float(np.sqrt(np.mean(total[mask] ** 2)))


@pytest.mark.parametrize("name", TRIALS)
def test_a_start_mid_motion_settles_in_seconds(name: str) -> None:
    whole = read_log(SHARED_DATA / name)
    rng = np.random.default_rng(20261208 + TRIALS.index(name))
    tuned = FilterConfig.tuned()
    assert tuned.settle_s > 0.0
    settled, unsettled = [], []
    for fraction in rng.uniform(0.2, 0.75, CUTS):
        t0 = whole.start + fraction * (whole.end - whole.start)
        log = whole.window(t0, min(whole.end, t0 + FIRST_S + 10.0))
        settled.append(first_seconds_rmse(log, tuned.settle_s))
        unsettled.append(first_seconds_rmse(log, 0.0))
    assert max(settled) < 30.0, f"cut at drawn moments, the first {FIRST_S:g} s: {settled} deg RMSE"
    assert np.mean(settled) < 0.75 * np.mean(unsettled), (settled, unsettled)


@pytest.mark.parametrize("settle", [-1.0, float("nan"), float("inf"), 1e400, "8", True, None])
def test_a_settling_that_is_no_length_is_refused_naming_it(settle: object) -> None:
    with pytest.raises(ConfigError, match="settle_s"):
        FilterConfig.tuned(settle_s=settle)

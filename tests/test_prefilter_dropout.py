"""The strapdown pre-filter through a drop-out of one sensor while the gyro goes on (docs/estimator.md,
"Pre-filter"): a real hand-held trial (tyrex, running with the phone in hand) with the accelerometer's
readings removed for 5 s in the middle of its motion. ``R_g`` keeps the accelerometer's low-pass true
through the gap, so the filter goes on from it; restarting it from the first reading after the gap (a
running hand's jolt taken for gravity) had sent the inclination 55° off for ~8 s. Kernels and numpy
references agree across the gap, and across one where the gyro drops out too (then the filter restarts).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hil.estimation import reference, reference_chain
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.metrics import compare_to_truth
from hil.estimation.multirate import MergePolicy, merge
from hil.estimation.prefilter import SignalPrefilter
from hil.estimation.sensors import KINDS, MergedSteps, SensorKind, SensorLog, SensorStream, StepFlag
from hil.logs import read_log
from hil.logs.replay import ReplayOptions, configure
from hil.scenario.paths import SHARED_DATA

TRIAL = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_RunningHand"
GAP_S = 5.0
AFTER_S = 20.0  # the window scored after the gap

pytestmark = pytest.mark.skipif(not TRIAL.exists(), reason=f"shared data not found: {TRIAL}")


def without_acc(log: SensorLog, t0: float, t1: float) -> SensorLog:
    """``log`` with the accelerometer's readings in ``[t0, t1]`` s removed."""
    acc = log.streams[SensorKind.ACC]
    keep = (acc.t < t0) | (acc.t > t1)
    return replace(
        log, streams={**log.streams, SensorKind.ACC: SensorStream(SensorKind.ACC, acc.t[keep], acc.xyz[keep])}
    )


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    """The trial with and without the drop-out (in the middle of the evaluated motion): each merged and
    run through the estimator's interface as ``hil replay --gyro-bias none`` builds it."""
    log = read_log(TRIAL)
    truth = log.truth
    t0 = 0.5 * (float(truth.t[truth.evaluate][0]) + log.end)
    t1 = t0 + GAP_S
    options = ReplayOptions(out_dir=tmp_path_factory.mktemp("replay"), gyro_bias="none")
    runs = {}
    for name, variant in (("whole", log), ("gap", without_acc(log, t0, t1))):
        choice, site, _ = configure(variant, options)
        steps, _ = merge(variant.streams, MergePolicy())
        est = choice.build(site).run(steps)
        score = compare_to_truth(truth.t, truth.R, truth.evaluate, est.t, est.quat)
        runs[name] = (steps, score)
    return t0, t1, runs


def inclination_after(score, t1: float) -> tuple[float, float]:
    """RMSE and max of the inclination error (deg) over the ``AFTER_S`` s after ``t1``."""
    sel = score.mask & (score.t >= t1) & (score.t <= t1 + AFTER_S)
    x = score.errors.inclination[sel]
    return float(np.sqrt(np.mean(x * x))), float(x.max())


def test_inclination_does_not_jump_when_the_accelerometer_comes_back(trial):
    t0, t1, runs = trial
    steps, score = runs["gap"]
    acc_ok = steps.valid(SensorKind.ACC)
    inside = (steps.t > t0 + 0.5) & (steps.t < t1 - 0.5)
    assert inside.any() and not acc_ok[inside].any()  # the drop-out reaches the filter as "not usable"
    rmse, worst = inclination_after(score, t1)
    rmse_whole, worst_whole = inclination_after(runs["whole"][1], t1)
    # restarting the low-pass: 55° at worst, RMSE ~20° over the 20 s after the gap (~3° without a gap)
    assert worst < worst_whole + 5.0
    assert rmse < rmse_whole + 2.0
    assert score.rmse.total < runs["whole"][1].rmse.total + 0.5


def test_kernels_equal_the_references_across_the_drop_out(trial):
    """The signal pre-filter (acc and mag filtered, strapdown frame) and the whole tuned chain on 25 s
    around the gap, kernel vs numpy reference; then the same with the gyro also missing for 0.5 s inside
    the gap, where the filter restarts from the accelerometer's first reading after it."""
    t0, t1, runs = trial
    steps, _ = runs["gap"]
    i0, i1 = np.searchsorted(steps.t, [t0 - 10.0, t1 + 10.0])
    window = steps.rows(int(i0), int(i1))
    both = np.flatnonzero((window.t > t0 + 2.0) & (window.t < t0 + 2.5))
    flags = window.flags.copy()
    flags[both] |= int(StepFlag.stale(SensorKind.GYR))  # the gyro stale too
    gyro_gap = replace(window, flags=flags)
    assert not gyro_gap.valid(SensorKind.GYR)[both].any()
    cut = {SensorKind.GYR: None, SensorKind.ACC: 0.47, SensorKind.MAG: 1.0}
    h = np.diff(window.t, prepend=window.t[0])
    back = int(np.flatnonzero(window.valid(SensorKind.ACC) & (window.t > t1))[0])  # the first reading after
    raw = window.acc[back]
    for case, restarts in ((window, False), (gyro_gap, True)):
        got = SignalPrefilter(cut, "strapdown").run(case)
        gyr, acc, mag = (np.where(case.valid(k)[:, None], case.value(k), np.nan) for k in KINDS)
        want = reference.signal_run(cut, "strapdown", h, gyr, acc, mag)
        for g, w in zip((got.gyr, got.acc, got.mag), want, strict=True):
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-9, equal_nan=True)
        assert np.isnan(got.acc[(window.t > t0 + 0.5) & (window.t < t1 - 0.5)]).all()
        jump = float(np.linalg.norm(got.acc[back] - raw))
        assert jump < 1e-12 if restarts else jump > 0.5  # a restart takes the raw reading; else it goes on
    config = FilterConfig.tuned()
    for case in (window, gyro_gap):
        got_chain = AttitudeFilter(config).run(case)
        ref = reference_chain.filter_run(config, case)
        np.testing.assert_allclose(got_chain.R, ref.R, rtol=0, atol=1e-8)
        np.testing.assert_array_equal(got_chain.flags, ref.flags)


def steps_of(t, gyr, acc, flags):
    n = len(t)
    return MergedSteps(t, gyr, acc, np.zeros((n, 3)), np.zeros((n, 3)), np.ones((n, 3), bool), flags)


def test_without_a_gyro_in_the_gap_the_filter_restarts():
    """Synthetic: the same gap with and without the gyro — held state vs a restart at the raw reading."""
    n = 400
    t = 0.01 * np.arange(n)
    gyr = np.tile([0.0, 0.0, 0.5], (n, 1))
    acc = np.tile([0.0, 0.0, 9.8], (n, 1)) + 0.5 * np.sin(7.0 * t)[:, None]
    acc[200:250] = np.nan
    cut = {SensorKind.ACC: 0.5, SensorKind.MAG: None, SensorKind.GYR: None}
    flags = np.zeros(n, np.int64)
    flags[200:250] = int(StepFlag.stale(SensorKind.ACC))
    kept = SignalPrefilter(cut, "strapdown").run(steps_of(t, gyr, acc, flags))
    flags[220:230] |= int(StepFlag.stale(SensorKind.GYR))
    restarted = SignalPrefilter(cut, "strapdown").run(steps_of(t, gyr, acc, flags))
    assert np.isnan(kept.acc[200:250]).all() and np.isnan(restarted.acc[200:250]).all()
    np.testing.assert_allclose(restarted.acc[250], acc[250], rtol=0, atol=1e-12)
    assert abs(kept.acc[250, 2] - 9.8) < 0.1 < abs(acc[250, 2] - 9.8)  # went on from the filtered value

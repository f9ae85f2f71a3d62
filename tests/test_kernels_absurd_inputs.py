"""The estimator's compiled kernels on readings that are numbers but absurd — 1e150 m/s², a field of 1e-160,
steps of a nanosecond or of 100 s, infinities, NaN — through the public per-sample calls, in any order; a
rate no sensor reads, and a step to a far timestamp, through every call.

A compiled kernel's float division by zero raises ZeroDivisionError (numba's Python error model), where the
numpy reference would give inf or NaN and go on: an absurd reading must be flagged or left out, never stop
the host's estimator task. Two such divisions were found by fuzzing and are pinned below: the gravity-only
start from a reading whose norm overflows, and the magnetic gate's low-pass cancelling to a zero norm."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation import reference, reference_chain
from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.params import EstimatorParams
from hil.estimation.sensors import MergedStep, MergedSteps, StepFlag
from hil.estimation.slots import GYRO_LIMIT, MAX_SUBSTEPS

ABSURD = st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e300, -1e300, 1e160, 1e150, -1e150, 1e-73, 1e-160, 5e-324]
)


def _reading(low: float, high: float) -> st.SearchStrategy[tuple[float, float, float] | None]:
    value = st.one_of(st.floats(low, high, allow_nan=False), ABSURD)
    return st.one_of(st.none(), st.tuples(value, value, value))


STEP = st.tuples(
    st.sampled_from([0.005, 0.005, 0.005, 1e-9, 5.0, 100.0, 1e-300]),
    _reading(-5.0, 5.0),
    _reading(-20.0, 20.0),
    _reading(-60.0, 60.0),
)


def _merged(t: float, h: float, gyr, acc, mag) -> MergedStep:  # type: ignore[no-untyped-def]
    return MergedStep(t, h, gyr, acc, mag, (0.0, 0.0, 0.0), (True, True, True), StepFlag(0))


def _finite_rotation(R: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(R))) and np.allclose(R @ R.T, np.eye(3), atol=1e-6)


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(["paper", "tuned"]), st.lists(STEP, min_size=1, max_size=60))
def test_a_filter_takes_any_sequence_of_absurd_readings_without_raising(config, steps):
    """Every step returns the estimate at its time, never an exception (NaN inputs are 'not usable',
    infinities and overflowing norms are left out)."""
    f = AttitudeFilter(FilterConfig() if config == "paper" else FilterConfig.tuned())
    t = 0.0
    for h, gyr, acc, mag in steps:
        t += h
        est = f.step(_merged(t, h, gyr, acc, mag))
        assert est.t == t
        assert _finite_rotation(est.R) and np.all(np.isfinite(est.omega))


@settings(max_examples=150, deadline=None)
@given(st.lists(STEP, min_size=1, max_size=60))
def test_the_estimator_alone_takes_any_sequence_of_absurd_readings_without_raising(steps):
    est = VariationalEstimator()
    for h, gyr, acc, mag in steps:
        got = est.update(h, gyr, acc, mag)
        assert _finite_rotation(got.R) and np.all(np.isfinite(got.omega))


def test_a_gravity_start_from_a_reading_whose_norm_overflows_waits_for_a_sane_one():
    """A filter awaiting its first attitude, given an acceleration of finite parts whose squared norm
    overflows (1e160 m/s²), once divided by zero in its gravity-only start; it is no direction, as
    everywhere else in the chain, and the next sane reading starts the filter."""
    f = AttitudeFilter(FilterConfig())
    f.step(_merged(0.0, 0.0, (0.0, 0.0, 0.0), (1e-73, 1e160, 14.7), (-1e160, -14.0, 37.9)))
    est = f.step(_merged(0.005, 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), (0.0, 20.0, -40.0)))
    assert _finite_rotation(est.R)


def test_the_magnetic_gate_survives_its_low_pass_cancelling_to_a_zero_norm():
    """A field of ~1e150 then a normal one a long step later (the low-pass gain 1): ``n + (m − n)``
    cancels to exactly 0, which the gate once divided by."""
    f = AttitudeFilter(FilterConfig.tuned())
    t = 0.0
    for h, mag in ((0.0, (0.0, 20.0, -40.0)), (0.005, (1e150, 0.0, 0.0)), (100.0, (-30.6, 10.7, 3.1))):
        t += h
        est = f.step(_merged(t, h, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), mag))
    for h in (0.005, 0.005, 100.0, 0.005):
        t += h
        est = f.step(_merged(t, h, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), (0.0, 20.0, -40.0)))
    assert _finite_rotation(est.R)


# --------------------------------------------------------------------------- rates no sensor reads
BEYOND = st.one_of(
    st.floats(GYRO_LIMIT, 1e308, exclude_min=True),
    st.sampled_from([1e12, 1e155, 1e200, 1e300, 1.7e308]),
).flatmap(lambda v: st.sampled_from([v, -v]))


def _steps(n: int = 400) -> MergedSteps:
    """A phone turning, at 200 Hz, every sensor usable."""
    t = 0.005 * np.arange(1, n + 1)
    gyr = np.column_stack([np.sin(0.7 * t), 1.5 * np.cos(0.3 * t), 0.5 * np.sin(0.1 * t)])
    acc = np.tile([0.3, 0.2, 9.8], (n, 1)) + 0.1 * np.sin(np.outer(t, [3.0, 5.0, 7.0]))
    mag = np.tile([0.0, 20.0, -40.0], (n, 1))
    return MergedSteps(t, gyr, acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 399), st.integers(0, 2), BEYOND), min_size=1, max_size=8))
def test_a_rate_no_sensor_reads_is_taken_as_no_rate_at_all(absurd):
    """A rate beyond :data:`GYRO_LIMIT` on any axis (finite: a 1e200 rad/s reading was taken, and left every
    later estimate NaN) is not usable, as NaN is: the filter (batch and live) and the estimator alone give
    the bits they give with NaN at those readings, and their numpy references agree."""
    steps, nan_steps = _steps(), _steps()
    for i, axis, value in absurd:
        steps.gyr[i, axis] = value
        nan_steps.gyr[i, axis] = math.nan
    for config in (FilterConfig(), FilterConfig.tuned()):
        got, want = AttitudeFilter(config).run(steps), AttitudeFilter(config).run(nan_steps)
        np.testing.assert_array_equal(got.R, want.R)
        np.testing.assert_array_equal(got.flags, want.flags)
        assert _finite_rotation(got.R[-1])
        live = AttitudeFilter(config)
        np.testing.assert_array_equal(np.array([live.step(s).R for s in steps.rows(0, 400)]), got.R)
        ref = reference_chain.filter_run(config, steps)
        np.testing.assert_array_equal(ref.R, reference_chain.filter_run(config, nan_steps).R)
        np.testing.assert_array_equal(ref.flags, got.flags)
    got, want = VariationalEstimator().update_batch(steps), VariationalEstimator().update_batch(nan_steps)
    np.testing.assert_array_equal(got.R, want.R)
    ref = reference.run(EstimatorParams(), np.eye(3), np.zeros(3), steps.t, steps.gyr, steps.acc, steps.mag)
    np.testing.assert_allclose(ref.R, got.R, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(ref.flags, got.flags)


# --------------------------------------------------------------------------- far timestamps
LONGEST = EstimatorParams().max_step_s * MAX_SUBSTEPS
FAR = st.one_of(
    st.floats(LONGEST, 1e300, exclude_min=True), st.sampled_from([math.inf, 1e8, LONGEST * (1 + 1e-15)])
)


@settings(max_examples=30, deadline=None)
@given(FAR, st.integers(1, 50))
def test_a_step_to_a_far_timestamp_is_refused_at_once_and_changes_nothing(far, at):
    """A step longer than :data:`MAX_SUBSTEPS` sub-steps (a far timestamp: 1e8 s had been split into 2e9
    sub-steps, a call of ~4 min; 1e10 s, hours) is a ValueError saying so, through every per-sample call,
    and the estimate goes on as though the call had not been made."""
    steps = _steps(60)
    live, clean = AttitudeFilter(FilterConfig.tuned()), AttitudeFilter(FilterConfig.tuned())
    est, est_clean = VariationalEstimator(), VariationalEstimator()
    for i, s in enumerate(steps.rows(0, 60)):
        if i == at:
            with pytest.raises(ValueError, match="at most"):
                live.step(MergedStep(s.t + far, far, s.gyr, s.acc, s.mag, s.age, s.fresh, s.flags))
            with pytest.raises(ValueError, match="at most"):
                est.update(far, s.gyr, s.acc, s.mag)
        np.testing.assert_array_equal(live.step(s).R, clean.step(s).R)
        h = s.h if i else 0.005
        np.testing.assert_array_equal(
            est.update(h, s.gyr, s.acc, s.mag).R, est_clean.update(h, s.gyr, s.acc, s.mag).R
        )


@pytest.mark.parametrize(
    ("far", "named"), [(LONGEST * 1.001, "step 30 at"), (1e8, "step 30 at"), (1e300, "step 31")]
)
def test_a_far_timestamp_in_a_batch_is_an_error_naming_its_step(far, named):
    """The batch paths refuse a far timestamp before they run, naming the step (at 1e300 s the later
    steps' times all round to the far one's: the first of them is named, as not after it); a step just
    within the bound is taken (sub-stepped)."""
    steps = _steps(60)
    steps.t[30:] += far
    with pytest.raises(ValueError, match=named):
        AttitudeFilter().run(steps)
    with pytest.raises(ValueError, match=named):
        VariationalEstimator().update_batch(steps)
    within = _steps(60)
    within.t[30:] += LONGEST * 0.999
    out = VariationalEstimator().update_batch(within)
    assert out.flags[30] & StepFlag.SUBSTEPPED and _finite_rotation(out.R[-1])

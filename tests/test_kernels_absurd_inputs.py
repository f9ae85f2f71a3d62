"""The estimator's compiled kernels on readings that are numbers but absurd — 1e150 m/s², a field of 1e-160,
steps of a nanosecond or of 100 s, infinities, NaN — through the public per-sample calls, in any order.

A compiled kernel's float division by zero raises ZeroDivisionError (numba's Python error model), where the
numpy reference would give inf or NaN and go on: an absurd reading must be flagged or left out, never stop
the host's estimator task. Two such divisions were found by fuzzing and are pinned below: the gravity-only
start from a reading whose norm overflows, and the magnetic gate's low-pass cancelling to a zero norm."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.sensors import MergedStep, StepFlag

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


@settings(max_examples=150, deadline=None)
@given(st.lists(STEP, min_size=1, max_size=60))
def test_the_estimator_alone_takes_any_sequence_of_absurd_readings_without_raising(steps):
    est = VariationalEstimator()
    for h, gyr, acc, mag in steps:
        est.update(h, gyr, acc, mag)


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

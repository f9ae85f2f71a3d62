"""The paper's first-order Butterworth pre-filter: its discrete form, response, variable step, resets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.prefilter import Prefilter, coefficients, filter_batch
from protocol.errors import ConfigError


def test_paper_form_at_1_rad_s():
    """(2 + h) x̄[k+1] = (2 − h) x̄[k] + h (x[k] + x[k+1]) with the paper's ω_c = 1 rad/s."""
    h = 0.01
    f = Prefilter(1.0, dim=1)
    f.update(h, [0.3])
    y = f.update(h, [1.7])[0]
    assert (2 + h) * y == pytest.approx((2 - h) * 0.3 + h * (0.3 + 1.7), abs=1e-15)
    alpha, beta = coefficients(1.0, h)
    assert alpha + 2 * beta == pytest.approx(1.0)  # unit DC gain


@pytest.mark.parametrize("cutoff", [0.5, 1.0, 10.0])
def test_step_response_matches_the_continuous_filter(cutoff):
    """A unit step settles as 1 − exp(−ω_c t) (the bilinear transform's error is O((ω_c h)²))."""
    h = 0.001
    t = np.arange(0, 5 / cutoff, h)
    x = np.ones((len(t), 1))
    x[0] = 0.0
    y = filter_batch(np.full(len(t), h), x, cutoff)[:, 0]
    expected = 1 - np.exp(-cutoff * (t - h / 2))  # the trapezoid sees the step half a sample early
    assert np.max(np.abs(y[1:] - expected[1:])) < 5 * (cutoff * h) ** 2 + 1e-3 * cutoff * h


def test_gain_at_the_cutoff_is_minus_3_db():
    h, cutoff = 0.001, 2.0
    t = np.arange(0, 40, h)
    y = filter_batch(np.full(len(t), h), np.sin(cutoff * t)[:, None], cutoff)[:, 0]
    late = y[t > 20]
    assert np.max(np.abs(late)) == pytest.approx(1 / math.sqrt(2), rel=2e-3)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(1e-4, 0.05), min_size=2, max_size=60),
    st.floats(0.1, 20.0),
    st.integers(0, 2**31 - 1),
)
def test_batch_equals_per_sample_for_any_steps(steps, cutoff, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(len(steps), 3))
    x[rng.random(len(steps)) < 0.1, 1] = np.nan  # invalid samples reset the filter
    batch = filter_batch(np.array(steps), x, cutoff)
    f = Prefilter(cutoff)
    single = np.array([f.update(h, row) for h, row in zip(steps, x, strict=True)])
    np.testing.assert_allclose(batch, single, atol=1e-12, equal_nan=True)


def test_constant_step_fast_path_equals_the_recursion():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(500, 3))
    const = filter_batch(np.full(500, 0.005), x, 1.0)
    jittered = filter_batch(np.full(500, 0.005) * (1 + 1e-9 * rng.random(500)), x, 1.0)  # forces the loop
    np.testing.assert_allclose(const, jittered, atol=1e-9)


def test_invalid_input_resets_and_restarts_at_the_next_valid_sample():
    f = Prefilter(1.0)
    f.update(0.01, [1.0, 1.0, 1.0])
    f.update(0.01, [5.0, 5.0, 5.0])
    assert all(math.isnan(v) for v in f.update(0.01, [np.nan, 0.0, 0.0]))
    assert f.output is None
    assert f.update(0.01, [7.0, 8.0, 9.0]) == (7.0, 8.0, 9.0)
    assert all(math.isnan(v) for v in f.update(0.01, [1.0, 2.0, 3.0], valid=False))


def test_bad_parameters_and_inputs():
    with pytest.raises(ConfigError, match="cut-off"):
        Prefilter(0.0)
    with pytest.raises(ConfigError):
        filter_batch(np.ones(3), np.ones((3, 3)), math.nan)
    f = Prefilter(1.0)
    f.update(0.01, [1, 2, 3])
    with pytest.raises(ValueError, match="positive"):
        f.update(0.0, [1, 2, 3])
    with pytest.raises(ValueError, match="components"):
        f.update(0.01, [1, 2])
    with pytest.raises(ValueError, match="step 2"):
        filter_batch(np.array([0.0, 0.01, -0.01]), np.ones((3, 3)))


# --------------------------------------------------------------------------- a phone's three signals
def turning_phone(rate: float = 0.5, seconds: float = 20.0, h: float = 0.005):
    """Gravity seen by a phone spinning about a horizontal body axis at ``rate`` rad/s."""
    t = np.arange(0.0, seconds, h)
    gyr = np.tile([rate, 0.0, 0.0], (len(t), 1))
    angle = rate * t
    acc = 9.81 * np.column_stack([np.zeros_like(t), np.sin(angle), np.cos(angle)])  # Rᵀ up, R = exp(x·angle)
    return t, gyr, acc


def steps_of(t, gyr, acc, mag=None):
    from hil.estimation.sensors import MergedSteps

    n = len(t)
    mag = np.tile([0.0, 20.0, -40.0], (n, 1)) if mag is None else mag
    return MergedSteps(t, gyr, acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64))


def test_strapdown_frame_prefilter_has_no_rotation_lag_where_the_body_frame_one_does():
    from hil.estimation.prefilter import SignalPrefilter
    from hil.estimation.sensors import SensorKind

    t, gyr, acc = turning_phone()
    cut = {SensorKind.ACC: 1.0}
    body = SignalPrefilter(cut, "body").run(steps_of(t, gyr, acc)).acc
    strap = SignalPrefilter(cut, "strapdown").run(steps_of(t, gyr, acc)).acc

    def angle_deg(a, b):
        c = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        return np.degrees(np.arccos(np.clip(c, -1, 1)))

    late = t > 10
    assert angle_deg(body[late], acc[late]).mean() == pytest.approx(np.degrees(np.arctan(0.5)), abs=1.0)
    assert angle_deg(strap[late], acc[late]).max() < 1e-4  # arccos resolution near 0


def test_signal_prefilter_batch_equals_steps_with_gaps_in_a_signal():
    from hil.estimation.prefilter import SignalPrefilter
    from hil.estimation.sensors import SensorKind

    rng = np.random.default_rng(2)
    t, gyr, acc = turning_phone(seconds=2.0)
    t = t + rng.uniform(0, 1e-4, len(t))
    acc = acc + 0.1 * rng.normal(size=acc.shape)
    acc[100:120] = np.nan  # not usable for a while: filter restarts
    cut = {SensorKind.ACC: 0.5, SensorKind.MAG: 2.0, SensorKind.GYR: 5.0}
    steps = steps_of(t, gyr, acc)
    batch = SignalPrefilter(cut, "strapdown").run(steps)
    live = SignalPrefilter(cut, "strapdown")
    rows = [live.step(s.h, s.gyr, s.acc, s.mag) for s in steps]
    nan3 = (np.nan,) * 3
    for k, name in enumerate(("gyr", "acc", "mag")):
        got = np.array([r[k] if r[k] is not None else nan3 for r in rows])
        np.testing.assert_allclose(getattr(batch, name), got, atol=1e-9, equal_nan=True)

"""Long series drawn readably (issue 28: a 700 s replay's rates.png was a solid band, attitude.png drew a
vertical line at every yaw wrap-around): the min/max envelope keeps every extreme exactly, an angle's line
is cut where it wraps, and a long replay's figures draw at most one point per bin."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from matplotlib.figure import Figure

from hil.plots.estimator import _line
from hil.plots.series import MAX_BINS, break_wraps, envelope, wrap_times

values = arrays(np.float64, st.integers(1, 5_000), elements=st.floats(-1e6, 1e6))


@given(y=values, bins=st.integers(1, 200))
@settings(max_examples=100, deadline=None)
def test_the_envelope_keeps_every_extreme_and_the_mean_between_them(y, bins):
    t = np.arange(len(y)) * 0.01
    env = envelope(t, y, bins=bins)
    if env is None:
        assert len(y) <= 2 * bins
        return
    assert len(env.t) == bins and np.all(np.diff(env.t) > 0)
    assert np.nanmax(env.high) == y.max() and np.nanmin(env.low) == y.min()  # exact, not averaged away
    full = ~np.isnan(env.mean)
    assert np.all(env.low[full] <= env.mean[full] + 1e-9 * np.abs(env.mean[full]) + 1e-12)
    assert np.all(env.mean[full] <= env.high[full] + 1e-9 * np.abs(env.mean[full]) + 1e-12)


@given(steps=arrays(np.float64, st.integers(2, 3_000), elements=st.floats(-40.0, 40.0)))
@settings(max_examples=100, deadline=None)
def test_an_angle_is_cut_where_it_wraps_never_drawn_across(steps):
    """A yaw turning any way, wrapped into [-180, 180): no two neighbours left on the line are more than
    half a turn apart, and every sample is still drawn at its own time."""
    yaw = (np.cumsum(steps) + 180.0) % 360.0 - 180.0
    t = np.arange(len(yaw)) * 0.02
    cut_t, cut = wrap_times(t, yaw), break_wraps(yaw)
    assert len(cut_t) == len(cut) and np.all(np.diff(cut_t) >= 0)
    jumps = np.abs(np.diff(cut))
    assert not np.any(jumps[np.isfinite(jumps)] > 180.0)
    np.testing.assert_array_equal(cut[np.isfinite(cut)], yaw)
    env = envelope(t, yaw, bins=max(1, len(yaw) // 5), period=360.0)
    if env is not None:
        jumps = np.abs(np.diff(env.mean))
        assert not np.any(jumps[np.isfinite(jumps)] > 180.0)


def test_a_long_series_draws_one_point_per_bin_with_its_band():
    """700 s at 200 Hz (a long replay): the line has MAX_BINS points, the band covers every sample."""
    t = np.arange(140_000) / 200.0
    y = np.sin(t) + np.random.default_rng(3).normal(0.0, 0.3, len(t))
    ax = Figure().add_subplot()
    _line(ax, t, y, "Ω̂x")
    (line,) = ax.get_lines()
    assert len(line.get_xdata()) == MAX_BINS
    (band,) = ax.collections
    lo, hi = band.get_paths()[0].vertices[:, 1].min(), band.get_paths()[0].vertices[:, 1].max()
    assert lo == y.min() and hi == y.max()
    short = Figure().add_subplot()
    _line(short, t[:500], y[:500], "short")
    assert len(short.get_lines()[0].get_xdata()) == 500 and not short.collections


def test_an_angle_turning_faster_than_half_a_turn_a_bin_is_cut_between_bins():
    """Hypothesis's find in CI: 39 deg a sample, five samples a bin, the wrap falling between two samples
    of one bin and not the next: two neighbouring bins' means 195 deg apart with no wrap between them.
    The line is cut there (it would read as turning the other way), every bin's mean still drawn."""
    steps = np.full(649, 39.0)
    steps[[0, 1, 2, 257]] = 0.0  # the example as Hypothesis shrank it
    yaw = (np.cumsum(steps) + 180.0) % 360.0 - 180.0
    t = np.arange(len(yaw)) * 0.02
    env = envelope(t, yaw, bins=len(yaw) // 5, period=360.0)
    assert env is not None
    jumps = np.abs(np.diff(env.mean))
    assert not np.any(jumps[np.isfinite(jumps)] > 180.0)
    assert np.all(np.diff(env.t) >= 0) and len(env.t) == len(env.mean) == len(env.low) == len(env.high)

"""Attitude error metrics (BROAD's definitions) on rotations whose errors are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from hil import so3
from hil.estimation.metrics import (
    AttitudeErrors,
    compare_to_truth,
    resample_quats,
    settling_time,
    truth_rates,
)


def test_pure_heading_and_pure_tilt_errors_split_exactly():
    truth = so3.exp(np.array([[0.3, -0.4, 1.0]] * 2))
    est = np.array([so3.exp([0, 0, np.radians(5.0)]) @ truth[0], so3.exp([np.radians(3.0), 0, 0]) @ truth[1]])
    err = AttitudeErrors.from_matrices(est, truth)
    np.testing.assert_allclose(err.total, [5.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(err.heading, [5.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(err.inclination, [0.0, 3.0], atol=1e-9)


def test_total_error_is_the_principal_angle_and_rmse_skips_masked_and_nan():
    rng = np.random.default_rng(0)
    truth = so3.exp(rng.normal(size=(50, 3)))
    est = np.array([so3.exp(rng.normal(size=3) * 0.1) @ r for r in truth])
    err = AttitudeErrors.from_matrices(est, truth)
    angles = np.degrees([so3.angle_between(a, b) for a, b in zip(est, truth, strict=True)])
    np.testing.assert_allclose(err.total, angles, atol=1e-7)
    mask = np.arange(50) < 40
    r = err.rmse(mask)
    assert r.n == 40 and r.total == pytest.approx(np.sqrt(np.mean(angles[:40] ** 2)))
    q = so3.matrix_to_quat(est)
    q[3] = np.nan
    assert np.isfinite(AttitudeErrors.from_quats(q, so3.matrix_to_quat(truth)).rmse().total)


def test_resampling_and_comparison_against_a_truth_series():
    t = np.linspace(0, 2, 201)
    rate = np.array([0.3, -0.2, 0.5])
    r = so3.exp(t[:, None] * rate)
    q = so3.matrix_to_quat(r)
    mid = np.array([0.555, 1.2345])
    np.testing.assert_allclose(
        so3.quat_to_matrix(resample_quats(t, q, mid)), so3.exp(mid[:, None] * rate), atol=1e-5
    )
    assert np.isnan(resample_quats(t, q, np.array([2.5]))).all()
    tm, w = truth_rates(t, r)
    np.testing.assert_allclose(w, np.tile(rate, (200, 1)), atol=1e-9)
    c = compare_to_truth(t, r, None, t, q, np.tile(rate, (201, 1)))
    assert c.rmse.total < 1e-6 and c.rate_rmse < 1e-9


def test_settling_time():
    t = np.arange(10.0)
    assert settling_time(t, np.array([9, 8, 7, 1, 2, 6, 1, 1, 0.5, 0.2]), 2.0) == 6.0
    assert settling_time(t, np.ones(10), 2.0) == 0.0
    assert settling_time(t, np.r_[np.ones(9), 5.0], 2.0) == float("inf")

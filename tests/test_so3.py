import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil import so3
from protocol.errors import NumericalError

vec = st.lists(st.floats(-4.0, 4.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@given(vec, vec)
def test_hat_is_cross_product_and_vee_inverts(a, b):
    np.testing.assert_allclose(so3.hat(a) @ b, np.cross(a, b), atol=1e-12)
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a, atol=0)


@given(vec)
@settings(max_examples=300)
def test_exp_is_rotation_and_log_inverts(phi):
    r = so3.exp(phi)
    assert so3.is_rotation(r, 1e-12)
    theta = np.linalg.norm(phi)
    if theta < np.pi - 1e-9:
        np.testing.assert_allclose(so3.log(r), phi, atol=1e-9)
    wrapped = theta % (2 * np.pi)
    assert so3.principal_angle(r) == pytest.approx(min(wrapped, 2 * np.pi - wrapped), abs=1e-9)
    np.testing.assert_allclose(so3.exp(so3.log(r)), r, atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-7, 1e-4, 1.0, np.pi - 1e-2, np.pi - 1e-7, np.pi])
def test_log_near_zero_and_pi(theta):
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    r = so3.exp(theta * axis)
    phi = so3.log(r)
    assert np.linalg.norm(phi) == pytest.approx(theta, abs=1e-9)
    np.testing.assert_allclose(so3.exp(phi), r, atol=1e-12)


def test_exp_batched_matches_single():
    phis = np.random.default_rng(1).normal(size=(5, 3))
    batch = so3.exp(phis)
    for p, r in zip(phis, batch, strict=True):
        np.testing.assert_allclose(so3.exp(p), r, atol=1e-15)


def test_project_restores_orthonormality_and_rejects_degenerate():
    r = so3.exp([0.2, 0.4, -0.1]) + 1e-6 * np.random.default_rng(0).normal(size=(3, 3))
    assert so3.orthonormality_error(so3.project(r)) < 1e-14
    with pytest.raises(NumericalError):
        so3.project(np.zeros((3, 3)))

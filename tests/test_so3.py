import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil import so3
from protocol.errors import NumericalError

vec = st.lists(st.floats(-4.0, 4.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@given(vec, vec)
def test_hat_is_cross_product_and_vee_inverts(a, b):
    np.testing.assert_allclose(so3.hat(a) @ b, np.cross(a, b), atol=1e-12)
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a, atol=0)


@given(vec)
@example(np.array([0.0, 3.136483, 0.15625]))  # 1.2 mrad from π: arccos's lost digits, magnified by 1/sin θ
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


# --------------------------------------------------------------------------- near π, hard
unit = (
    st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3)
    .map(np.array)
    .filter(lambda v: np.linalg.norm(v) > 1e-3)
)


@given(unit, st.floats(0.0, 1e-6))
@settings(max_examples=300)
def test_log_just_below_pi_recovers_angle_and_axis_up_to_the_antipodal_sign(axis, gap):
    axis = axis / np.linalg.norm(axis)
    theta = np.pi - gap
    r = so3.exp(theta * axis)
    phi = so3.log(r)
    assert np.linalg.norm(phi) == pytest.approx(theta, abs=1e-7)
    np.testing.assert_allclose(so3.exp(phi), r, atol=1e-12)
    n = phi / np.linalg.norm(phi)
    assert abs(abs(n @ axis) - 1.0) < 1e-7  # at exactly π, n and -n are the same rotation


@given(unit)
def test_log_at_exactly_pi_and_of_slightly_non_orthonormal_input(axis):
    axis = axis / np.linalg.norm(axis)
    r = 2 * np.outer(axis, axis) - np.eye(3)  # the rotation by π about axis, built without exp
    phi = so3.log(r)
    assert np.linalg.norm(phi) == pytest.approx(np.pi, abs=1e-9)
    np.testing.assert_allclose(so3.exp(phi), r, atol=1e-9)
    noisy = so3.exp(2.0 * axis) + 1e-10
    assert so3.principal_angle(noisy) == pytest.approx(2.0, abs=1e-8)


# --------------------------------------------------------------------------- quaternions
@given(vec)
def test_quaternion_round_trip_and_convention(phi):
    r = so3.exp(phi)
    q = so3.matrix_to_quat(r)
    assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(so3.quat_to_matrix(q), r, atol=1e-12)
    np.testing.assert_allclose(so3.quat_to_matrix(-q), r, atol=1e-12)


def test_quaternion_of_known_rotations_and_batches():
    half = np.sqrt(0.5)
    np.testing.assert_allclose(so3.matrix_to_quat(so3.exp([0, 0, np.pi / 2])), [half, 0, 0, half], atol=1e-15)
    np.testing.assert_allclose(np.abs(so3.matrix_to_quat(so3.exp([np.pi, 0, 0]))), [0, 1, 0, 0], atol=1e-15)
    phis = np.random.default_rng(4).normal(size=(7, 3)) * 2
    rs = so3.exp(phis)
    np.testing.assert_allclose(so3.quat_to_matrix(so3.matrix_to_quat(rs)), rs, atol=1e-12)
    with pytest.raises(NumericalError):
        so3.quat_to_matrix([0, 0, 0, 0])


# --------------------------------------------------------------------------- float kernels
@given(vec, vec)
@settings(max_examples=200)
def test_float_kernels_agree_with_the_array_functions(phi, v):
    p = tuple(float(x) for x in phi / 3)
    r = so3.exp(phi / 3)
    np.testing.assert_allclose(np.array(so3.exp_f(*p)).reshape(3, 3), r, atol=1e-14)
    np.testing.assert_allclose(so3.rotate_f(*p, *v), r @ v, atol=1e-13)
    q = so3.exp(v / 5)
    prod = so3.matmul_f(tuple(r.ravel()), tuple(q.ravel()))
    np.testing.assert_allclose(np.array(prod).reshape(3, 3), r @ q, atol=1e-14)
    m = r + np.diag([2.0, 2.0, 2.0])
    np.testing.assert_allclose(so3.solve3_f(tuple(m.ravel()), tuple(v)), np.linalg.solve(m, v), atol=1e-12)


@pytest.mark.parametrize("theta2", [0.0, 1e-12, 9.9e-9, 1.01e-8, 1e-6, 1e-4, 0.0099, 0.0101, 0.5, 9.0])
def test_rodrigues_coefficients_are_accurate_everywhere(theta2):
    """Against high-precision values (mpmath-free: the series to many terms in exact rationals)."""
    from fractions import Fraction

    x = Fraction(theta2)
    fact = [1]
    for k in range(1, 40):
        fact.append(fact[-1] * k)

    def series(offset: int) -> float:  # Σ (−x)^k / (2k + offset)!
        return float(sum((-x) ** k / fact[2 * k + offset] for k in range(15)))

    a, b, c = so3.rodrigues_coefficients(theta2)
    assert a == pytest.approx(series(1), rel=1e-15, abs=1e-16)
    assert b == pytest.approx(series(2), rel=2e-15, abs=1e-16)
    assert c == pytest.approx(series(3), rel=2e-15, abs=1e-16)


def test_reorthonormalize_squares_the_error_and_keeps_the_rotation():
    r = so3.exp([0.3, -1.0, 2.0])
    for eps in (1e-4, 1e-6):
        noisy = r + eps * np.random.default_rng(0).normal(size=(3, 3))
        fixed = np.array(so3.reorthonormalize_f(tuple(noisy.ravel()))).reshape(3, 3)
        assert so3.orthonormality_error(fixed) < 10 * so3.orthonormality_error(noisy) ** 2 + 1e-15
        assert so3.angle_between(fixed, r) < 3 * eps


def test_solve3_rejects_singular_systems():
    with pytest.raises(NumericalError, match="singular"):
        so3.solve3_f((1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0))


def test_the_float_log_is_the_numpy_log_at_every_angle():
    """so3.log_f (the simulated phone's compiled sampler and the telemetry rows use it) against so3.log:
    random rotations, tiny ones, and rotations within 1 mrad of π about each axis and about random axes
    (where the axis comes from the symmetric part), to rounding."""
    rng = np.random.default_rng(11)
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0.0, np.pi, 200), rng.uniform(0.0, 1e-4, 50),
                             np.pi - rng.uniform(0.0, 1e-3, 50)])  # fmt: skip
    vectors = np.concatenate([axes * angles[:, None], np.pi * (1 - 1e-7) * np.eye(3), -np.pi * np.eye(3)])
    for phi in vectors:
        R = so3.exp(phi)
        got = np.array(so3.log_f(tuple(R.ravel().tolist())))
        np.testing.assert_allclose(got, so3.log(R), rtol=0, atol=5e-15)
        np.testing.assert_allclose(so3.exp(got), R, rtol=0, atol=2e-14)  # exp adds its own rounding

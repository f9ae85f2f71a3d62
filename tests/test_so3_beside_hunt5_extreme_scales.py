"""Rotations just beside the tested scales: rotation vectors too long to square in float64 and quaternions
far from unit norm.

Found by the fifth hunt:

- ``so3.exp`` of a finite rotation vector longer than 1.3e154 rad (its ``|φ|²`` overflows) returned a
  matrix of NaN; ``so3.exp_f`` and ``so3.rotate_f`` raised a bare ValueError (``math.sin(inf)``) from
  Python and returned NaN when compiled, so the three disagreed, and ``rodrigues_coefficients(inf)``
  likewise;
- ``so3.quat_to_matrix`` refused finite non-zero quaternions of norm 1e-300 or 1e300 as "zero or
  non-finite" (their squares underflowed or overflowed), and one of norm 1e-160 was normalised by a norm of
  denormals into a matrix 3e-5 from orthonormal, without a word;
- ``so3.project`` of a non-finite matrix raised numpy's bare LinAlgError.

Now every finite rotation vector gives a rotation, the same from numpy, the float kernel and the compiled
kernel; a quaternion at any finite non-zero scale gives its rotation; the rest is a NumericalError.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil import so3
from hil.jit import _numba
from hil.so3 import floats
from protocol.errors import NumericalError

_nb = _numba()  # numba with hil's jitable functions registered, as the compiled kernels see them
COMPILED = {
    "exp_f": _nb.njit(floats.exp_f),
    "rotate_f": _nb.njit(floats.rotate_f),
    "rodrigues_coefficients": _nb.njit(floats.rodrigues_coefficients),
}

axes = (
    st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3)
    .map(np.array)
    .filter(lambda v: np.linalg.norm(v) > 1e-3)
    .map(lambda v: v / np.linalg.norm(v))
)
long_lengths = st.floats(1.35e154, 1.7e308, allow_nan=False, allow_infinity=False)


def _assert_rotation(r: np.ndarray, where: str) -> None:
    assert np.all(np.isfinite(r)), f"{where}: {r}"
    assert so3.orthonormality_error(r) < 1e-14, where
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14), where


@settings(max_examples=150, deadline=None)
@given(axes, long_lengths, st.lists(st.floats(-10.0, 10.0, allow_nan=False), min_size=3, max_size=3))
@example(np.array([0.6, 0.0, 0.8]), 1e160, [1.0, 0.0, 0.0])
@example(np.array([1.0, 0.0, 0.0]), 1.7976931348623157e308, [0.0, 1.0, 0.0])
def test_a_rotation_vector_too_long_to_square_is_a_rotation_about_its_axis_everywhere(axis, length, v):
    phi = axis * length
    # the case: φ finite, |φ|² overflowing
    assert np.all(np.isfinite(phi)) and not math.isfinite(sum(x * x for x in phi.tolist()))
    r = so3.exp(phi)
    _assert_rotation(r, "so3.exp")
    np.testing.assert_allclose(r @ axis, axis, atol=1e-14)  # a turn about φ's own axis
    np.testing.assert_allclose(so3.exp(-phi) @ r, np.eye(3), atol=1e-14)  # exp(−φ) undoes it
    p = tuple(phi.tolist())
    for name in ("exp_f", "rotate_f"):
        python = np.array(floats.exp_f(*p) if name == "exp_f" else floats.rotate_f(*p, *v))
        compiled = np.array(COMPILED[name](*p) if name == "exp_f" else COMPILED[name](*p, *v))
        expected = r.ravel() if name == "exp_f" else r @ np.asarray(v)
        np.testing.assert_allclose(python, expected, rtol=0, atol=1e-13, err_msg=name)
        np.testing.assert_array_equal(compiled, python, err_msg=f"compiled {name}")
    batch = so3.exp(np.stack([phi, 0.5 * axis]))  # a long vector beside an ordinary one in one batch
    np.testing.assert_array_equal(batch[0], r)
    np.testing.assert_array_equal(batch[1], so3.exp(0.5 * axis))


def test_rodrigues_coefficients_of_an_overflowed_square_are_their_limits_in_both_codes():
    assert floats.rodrigues_coefficients(math.inf) == (0.0, 0.0, 0.0)
    assert COMPILED["rodrigues_coefficients"](math.inf) == (0.0, 0.0, 0.0)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4)
    .map(np.array)
    .filter(lambda q: np.linalg.norm(q) > 0.1),
    st.integers(-1070, 1020),
)
@example(np.array([0.6, 0.8, 0.0, 0.0]), -996)  # norm ~1e-300
@example(np.array([0.6, 0.8, 0.0, 0.0]), 997)  # norm ~1e300
@example(np.array([0.5, 0.5, 0.0, 0.0]), -531)  # 1e-160: squares denormal, the norm 1e-5 off
@example(np.array([0.0, 0.0, 0.984375, 0.125]), 333)  # CI's draw: 1.1e-15 apart, within rounding
def test_a_quaternion_at_any_finite_non_zero_scale_gives_its_rotation(q0, k):
    q = q0 * 2.0**k  # may round in the denormal range; scaling it back up by powers of two is exact
    assert np.any(q != 0.0)
    up = (q * 2.0 ** (-k // 2)) * 2.0 ** (-k - (-k // 2))
    r = so3.quat_to_matrix(q)
    _assert_rotation(r, "quat_to_matrix")
    # the two normalise in different steps (divided by the largest component first, or not): a few ulps
    # apart (q0 [0, 0, 0.984375, 0.125] at 2**333: 1.1e-15 on an entry of 1)
    np.testing.assert_allclose(r, so3.quat_to_matrix(up), rtol=0, atol=4e-15)
    stacked = so3.quat_to_matrix(np.stack([q, q0]))  # another scale in the same batch
    np.testing.assert_array_equal(stacked[0], r)
    np.testing.assert_array_equal(stacked[1], so3.quat_to_matrix(q0))


@pytest.mark.parametrize("bad", [[0.0, 0.0, 0.0, 0.0], [np.nan, 1.0, 0.0, 0.0], [1.0, np.inf, 0.0, 0.0]])
def test_a_zero_or_non_finite_quaternion_is_a_numerical_error_naming_it(bad):
    with pytest.raises(NumericalError, match="zero or not finite"):
        so3.quat_to_matrix(bad)
    with pytest.raises(NumericalError, match=r"at index \[2\]"):
        so3.quat_to_matrix([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], bad])


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_projecting_a_non_finite_matrix_is_a_numerical_error(bad):
    m = so3.exp([0.1, 0.2, 0.3])
    m[1, 2] = bad
    with pytest.raises(NumericalError, match="non-finite"):
        so3.project(m)

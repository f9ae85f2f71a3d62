"""Rotations and VSCMG geometry given values that parse but are no rotation, angle or geometry.

Found by the sixth hunt:

- ``so3.log`` of a matrix that is no rotation answered a number without a word: the zero matrix a turn of
  π about x, the reflection ``-I`` NaN, ``diag(1, 1, -1)`` zero, a rotation off orthonormal by 1e-3 a
  vector off by as much, a (4, 4) matrix zeros, NaN entries NaN;
- ``so3.euler_zyx`` of inf raised a bare ValueError ("math domain error"), of a string a bare TypeError,
  of NaN a matrix of NaN;
- ``vscmg.pyramid`` (and ``cubesat_1u``) given ``beta="x"`` raised a bare TypeError, ``radius_m="x"``
  numpy's UFuncTypeError; ``spin_axes_at`` of NaN or inf gimbal angles answered NaN axes, of the wrong
  count numpy's bare broadcast ValueError.

Now each is the project's typed error (NumericalError for so3, ConfigError for the geometry) naming the
argument; every true rotation still has its log, every finite angle its matrix.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil import so3
from hil.vscmg import cubesat_1u, pyramid, spin_axes_at
from protocol.errors import ConfigError, NumericalError

finite_vec = st.lists(st.floats(-4.0, 4.0, allow_nan=False), min_size=3, max_size=3).map(np.array)
absurd = st.sampled_from([math.nan, math.inf, -math.inf])


# --------------------------------------------------------------------------- so3.log
@settings(max_examples=200, deadline=None)
@given(
    finite_vec, st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=9, max_size=9), st.floats(1e-5, 1.0)
)
@example(np.array([0.3, 0.2, 0.1]), [1.0] * 9, 1e-3)
def test_log_of_a_matrix_off_orthonormal_is_a_numerical_error_naming_it(phi, noise, scale):
    noise = np.asarray(noise).reshape(3, 3)
    if np.linalg.norm(noise) < 0.1:
        noise = noise + np.eye(3)
    r = so3.exp(phi) + scale * noise / np.linalg.norm(noise)
    if so3.orthonormality_error(r) <= 2e-6:  # a perturbation along the group: still a rotation to rounding
        return
    with pytest.raises(NumericalError, match=r"so3\.log: not a rotation"):
        so3.log(r)


@settings(max_examples=100, deadline=None)
@given(finite_vec, st.integers(0, 2))
def test_log_of_a_reflection_is_a_numerical_error(phi, axis):
    flip = np.eye(3)
    flip[axis, axis] = -1.0
    for r in (so3.exp(phi) @ flip, -so3.exp(phi)):
        with pytest.raises(NumericalError, match="determinant"):
            so3.log(r)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((3, 3)),
        np.full((3, 3), np.nan),
        np.diag([np.inf, 1.0, 1.0]),
        np.eye(4),
        np.eye(2),
        np.ones(9),
    ],
    ids=["zeros", "nan", "inf", "4x4", "2x2", "flat"],
)
def test_log_of_what_is_no_rotation_matrix_is_a_numerical_error(bad):
    with pytest.raises(NumericalError, match=r"so3\.log"):
        so3.log(bad)


@settings(max_examples=200, deadline=None)
@given(finite_vec, st.floats(0.0, 1e-9))
def test_log_of_a_rotation_with_rounding_noise_still_inverts_exp(phi, eps):
    r = so3.exp(phi) + eps
    phi_back = so3.log(r)
    assert np.all(np.isfinite(phi_back)) and np.linalg.norm(phi_back) <= np.pi + 1e-9
    assert so3.angle_between(so3.exp(phi_back), r) < 1e-7


# --------------------------------------------------------------------------- so3.euler_zyx
@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2), st.one_of(absurd, st.sampled_from(["x", "", None, [1.0], 10**400, True])))
@example(0, math.inf)
@example(2, "x")
def test_euler_of_an_angle_that_is_no_finite_number_is_a_numerical_error_naming_it(which, bad):
    angles: list[object] = [10.0, -20.0, 30.0]
    angles[which] = bad
    name = ("roll_deg", "pitch_deg", "yaw_deg")[which]
    with pytest.raises(NumericalError, match=rf"so3\.euler_zyx\.{name}"):
        so3.euler_zyx(*angles)  # type: ignore[arg-type]


@settings(max_examples=200, deadline=None)
@given(*[st.floats(-1e300, 1e300, allow_nan=False, allow_infinity=False)] * 3)
@example(-0.0, 1e160, 5e-324)
def test_euler_of_every_finite_angle_is_a_rotation(roll, pitch, yaw):
    r = so3.euler_zyx(roll, pitch, yaw)
    assert np.all(np.isfinite(r)) and so3.is_rotation(r, 1e-12)


# --------------------------------------------------------------------------- VSCMG geometry
@pytest.mark.parametrize("key", ["beta", "radius_m", "height_m"])
@pytest.mark.parametrize("bad", ["x", None, [0.1, 0.2], math.nan, math.inf, -math.inf])
def test_pyramid_argument_that_is_no_finite_number_is_a_config_error_naming_it(key, bad):
    with pytest.raises(ConfigError, match=rf"pyramid\.{key}"):
        pyramid(4, **{key: bad})


def test_cubesat_with_a_beta_that_is_no_number_is_a_config_error_naming_it():
    with pytest.raises(ConfigError, match=r"pyramid\.beta"):
        cubesat_1u(beta="x")  # type: ignore[arg-type]


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 3), absurd)
def test_spin_axes_at_a_non_finite_gimbal_angle_is_a_config_error_naming_the_unit(i, bad):
    angles = [0.1, -0.2, 0.3, 0.4]
    angles[i] = bad
    with pytest.raises(ConfigError, match=rf"spin_axes_at\.gimbal_angles\[{i}\]"):
        spin_axes_at(pyramid(4), angles)


@pytest.mark.parametrize("angles", [[0.0] * 3, [0.0] * 5, [[0.0] * 4], "abcd"])
def test_spin_axes_at_the_wrong_count_of_angles_is_a_config_error(angles):
    with pytest.raises(ConfigError, match=r"spin_axes_at\.gimbal_angles"):
        spin_axes_at(pyramid(4), angles)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=4, max_size=4))
def test_spin_axes_at_finite_angles_are_unit_vectors_perpendicular_to_their_gimbals(angles):
    units = pyramid(4)
    s = spin_axes_at(units, angles)
    g = np.array([u.gimbal_axis for u in units])
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", s, g), 0.0, atol=1e-12)

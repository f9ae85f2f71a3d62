"""Schaub–Junkins VSCMG steering: torque delivered, CMG/wheel blending by δ, null motion, limits."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.control.steering import Saturation, SteeringParams, VscmgSteering
from hil.vscmg import air_bearing_testbed, cubesat_1u
from protocol.errors import ConfigError

PARAMS = cubesat_1u()
SINGULAR_GIMBALS = np.radians([90.0, -90.0, 90.0, -90.0])  # a zero-momentum singularity of the pyramid
W0 = np.full(4, 400.0)


@settings(max_examples=40, deadline=None)
@given(
    gimbals=st.lists(st.floats(-3.0, 3.0), min_size=4, max_size=4),
    torque=st.lists(st.floats(-2e-4, 2e-4), min_size=3, max_size=3),
)
def test_unsaturated_commands_deliver_the_required_torque(gimbals, torque):
    steer = VscmgSteering(PARAMS)
    out = steer.solve(torque, gimbals, W0, 0.02)
    if out.scale[0] == 1.0 and out.saturation[0] == 0:
        np.testing.assert_allclose(out.torque[0], torque, atol=1e-12 + 1e-9 * np.linalg.norm(torque))
    # always: the command is finite and within every limit
    assert np.all(np.abs(out.gimbal_rate) <= PARAMS.limits.max_gimbal_rate * (1 + 1e-12))
    assert np.all(np.abs(out.rotor_accel) <= PARAMS.limits.max_rotor_accel * (1 + 1e-12))


def test_delta_matches_its_definition_and_its_gradient():
    steer = VscmgSteering(PARAMS)
    g = np.array([0.3, -0.2, 0.5, 0.1])
    _, D1 = steer.jacobians(g[None], W0[None])
    h = PARAMS.nominal_wheel_momentum
    assert steer.delta(g, W0)[0] == pytest.approx(np.linalg.det(D1[0] @ D1[0].T / h**2), rel=1e-12)
    num = [(steer.delta(g + e * 1e-6, W0) - steer.delta(g - e * 1e-6, W0))[0] / 2e-6 for e in np.eye(4)]
    np.testing.assert_allclose(steer.delta_gradient(g, W0)[0], num, rtol=1e-6)
    assert steer.delta(SINGULAR_GIMBALS, W0)[0] < 1e-20
    assert steer.delta(np.zeros(4), W0)[0] == pytest.approx(32 / 27, rel=1e-9)


def test_compiled_momentum_and_delta_equal_their_numpy_forms():
    """The host's every-tick momentum and δ run as kernels: Σ I_Ws Ω s and det(D₁ D₁ᵀ)/h̄⁶ from the numpy
    axes and Jacobians agree to rounding, row by row, over a batch of random states."""
    steer = VscmgSteering(PARAMS)
    rng = np.random.default_rng(3)
    g, w = rng.uniform(-3.0, 3.0, (6, 4)), rng.uniform(-50.0, 600.0, (6, 4))
    s, _ = steer.axes(g)
    want = np.einsum("bn,bni->bi", steer.I_ws * w, s)
    np.testing.assert_allclose(steer.momentum(g, w), want, rtol=1e-13, atol=1e-16)
    np.testing.assert_allclose(steer.momentum(g[2], w[2]), want[2:3], rtol=1e-13, atol=1e-16)
    _, D1 = steer.jacobians(g, w)
    delta = np.linalg.det(D1 @ np.swapaxes(D1, -1, -2)) / PARAMS.nominal_wheel_momentum**6
    np.testing.assert_allclose(steer.delta(g, w), delta, rtol=1e-10, atol=1e-14)


def test_cmg_mode_away_from_singularities_wheel_mode_at_one():
    steer = VscmgSteering(PARAMS)
    torque = np.array([0.0, 0.0, 1e-4])  # about z: the singular direction of SINGULAR_GIMBALS
    far = steer.solve(torque, np.zeros(4), W0, 0.02)
    near = steer.solve(torque, SINGULAR_GIMBALS, W0, 0.02)
    # away: gimbals do the work, the rotors hardly change speed
    assert np.max(np.abs(far.rotor_accel)) * 1e-5 < 1e-3 * np.linalg.norm(torque)
    # at the singularity the gimbals cannot help about z: the rotors deliver it, with bounded commands
    np.testing.assert_allclose(near.torque[0], torque, rtol=1e-9, atol=1e-15)
    assert near.wheel_weight[0, 0] > 1e3 * far.wheel_weight[0, 0]
    assert np.max(np.abs(near.gimbal_rate)) < 1e-6
    assert np.max(np.abs(near.rotor_accel)) > 1.0
    # a pure CMG pseudo-inverse near the singularity would need far larger gimbal rates than VSCMG steering
    slightly_off = SINGULAR_GIMBALS + np.radians([0.5, -0.5, 0.5, -0.5])
    cmg = VscmgSteering(PARAMS, SteeringParams(wheel_weight=0.0, singular_eps=1e-12))  # undamped
    vscmg = steer.solve(torque, slightly_off, W0, 0.02)
    pure = cmg.solve(torque, slightly_off, W0, 0.02)
    assert pure.saturation[0] & Saturation.GIMBAL_RATE or np.max(np.abs(pure.gimbal_rate)) > 0.5
    assert np.max(np.abs(vscmg.gimbal_rate)) < 0.1 * np.max(np.abs(pure.gimbal_rate))
    assert not vscmg.saturation[0] & Saturation.DAMPED  # the wheels carry the axis: nothing to damp
    # the same CMG-only array with the default damping: damped least squares bounds its gimbal rates
    damped = VscmgSteering(PARAMS, SteeringParams(wheel_weight=0.0)).solve(torque, slightly_off, W0, 0.02)
    assert damped.saturation[0] & Saturation.DAMPED
    assert np.max(np.abs(damped.gimbal_rate)) < 0.5 * np.max(np.abs(pure.gimbal_rate))


def test_null_motion_is_torque_free_and_raises_delta():
    steer = VscmgSteering(PARAMS, SteeringParams(null_gain=1.0))
    plain = VscmgSteering(PARAMS)
    g = SINGULAR_GIMBALS + np.radians([5.0, -4.0, 3.0, -6.0])
    torque = np.array([2e-5, -1e-5, 3e-5])
    a, b = steer.solve(torque, g, W0, 0.02), plain.solve(torque, g, W0, 0.02)
    np.testing.assert_allclose(a.torque, b.torque, atol=1e-15)
    assert np.any(np.abs(a.gimbal_rate - b.gimbal_rate) > 1e-4)
    # following the null motion alone increases δ
    null = steer.solve(np.zeros(3), g, W0, 0.02)
    d0 = steer.delta(g, W0)[0]
    assert steer.delta(g + 0.01 * null.gimbal_rate[0], W0)[0] > d0


def test_null_motion_returns_rotor_speeds_slower_than_the_drives_answer():
    """On the testbed's tetrahedron (δ ≈ 0.07 at rest: wheel weight near its W_s0 Ω̄²) a rotor 2 rad/s above
    nominal is brought back at no more than k k_Ω W_s0 exp(−μ δ) per second — under 1/s, where a rotor
    drive answers at 1/τ ≈ 7/s — torque-free; the speed term divided by Ω̄ only (not Ω̄²) asked ~190 rad/s²
    for it and put the array into a limit cycle through the drives."""
    params = air_bearing_testbed()
    p = SteeringParams(null_gain=0.5)
    steer = VscmgSteering(params, p)
    nominal = params.nominal_rotor_speed
    w = np.full((1, 3), nominal)
    w[0, 0] += 2.0
    out = steer.solve(np.zeros(3), np.zeros(3), w, 0.02)
    rate = p.null_gain * p.speed_gain * p.wheel_weight * np.exp(-p.mu * out.delta[0])  # 1/s
    assert 0.0 < -out.rotor_accel[0, 0] <= rate * 2.0 < 2.0
    np.testing.assert_allclose(out.torque, 0.0, atol=1e-12)
    at_nominal = steer.solve(np.zeros(3), np.zeros(3), np.full((1, 3), nominal), 0.02)
    np.testing.assert_allclose(at_nominal.rotor_accel, 0.0, atol=1e-12)  # γ = 0 is a δ extremum too


def test_limits_scale_the_command_and_keep_its_direction():
    steer = VscmgSteering(PARAMS)
    big = np.array([9e-3, -3e-3, 6e-3])
    out = steer.solve(big, [0.2, 0.1, -0.3, 0.4], W0, 0.02)
    assert out.saturation[0] & Saturation.GIMBAL_RATE
    assert out.scale[0] < 1.0
    assert np.max(np.abs(out.gimbal_rate)) == pytest.approx(PARAMS.limits.max_gimbal_rate)
    np.testing.assert_allclose(
        out.torque[0] / np.linalg.norm(out.torque[0]), big / np.linalg.norm(big), atol=1e-9
    )


def test_a_rotor_at_its_speed_limit_leaves_wheel_mode():
    steer = VscmgSteering(PARAMS)
    w = W0.copy()
    w[0] = PARAMS.limits.max_rotor_speed - 0.01
    torque = np.array([0.0, 0.0, 1e-4])
    free = steer.solve(torque, SINGULAR_GIMBALS, W0, 0.02)
    unit0_push = free.rotor_accel[0, 0]
    w_sign = PARAMS.limits.max_rotor_speed - 0.01 if unit0_push > 0 else PARAMS.limits.min_rotor_speed + 0.01
    w[0] = w_sign
    out = steer.solve(torque, SINGULAR_GIMBALS, w, 0.02)
    assert out.saturation[0] & Saturation.ROTOR_SPEED
    assert out.rotor_accel[0, 0] == 0.0
    assert np.all(np.isfinite(out.gimbal_rate))


def test_batch_rows_are_independent_and_bad_params_refused():
    steer = VscmgSteering(PARAMS)
    g = np.array([[0.1, 0.2, 0.3, 0.4], [-0.3, 0.0, 0.9, 0.2]])
    L = np.array([[1e-5, 0, 0], [0, 2e-5, -1e-5]])
    both = steer.solve(L, g, np.stack([W0, W0]), 0.02)
    one = steer.solve(L[1], g[1], W0, 0.02)
    np.testing.assert_allclose(both.gimbal_rate[1], one.gimbal_rate[0], rtol=1e-12)
    with pytest.raises(ConfigError, match="mu"):
        SteeringParams(mu=-1.0)
    with pytest.raises(ConfigError):
        replace(SteeringParams(), gimbal_weight=0.0)


# ------------------------------------------------------------------- no authority: damped least squares
def test_stopped_rotors_after_a_reset_make_no_singular_solve():
    """Issue 16, finding 1: a board that reset reports its rotors stopped. Then D₁ = 0 (no gimbal
    authority) and the speed rule takes every rotor that would have to slow below its minimum speed out of
    wheel mode, so Q W Qᵀ loses rank — the undamped solve divided by zero (LinAlgError in numpy,
    ZeroDivisionError in the kernel). The damped solve returns a bounded command, flagged DAMPED, that
    delivers torque only where the array has authority."""
    from hil.control import steering_reference as ref

    steer = VscmgSteering(PARAMS, SteeringParams(null_gain=0.5))
    stopped = np.zeros(4)
    rng = np.random.default_rng(5)
    torques = rng.normal(size=(32, 3)) * 1e-3
    got = steer.solve(torques, np.zeros((32, 4)), np.zeros((32, 4)), 0.02)
    want = ref.solve(steer, torques, np.zeros((32, 4)), np.zeros((32, 4)), 0.02)
    singular = 0
    for b in range(32):
        kept = got.wheel_weight[b] > 0
        D0, _ = steer.jacobians(np.zeros((1, 4)), stopped[None])
        singular += np.linalg.matrix_rank(D0[0][:, kept]) < 3  # the undamped Q W Qᵀ was singular
    assert singular >= 8
    assert np.all(got.saturation & Saturation.DAMPED)
    for out in (got, want):
        assert np.all(np.isfinite(out.rotor_accel)) and np.all(np.isfinite(out.gimbal_rate))
        assert np.all(np.abs(out.rotor_accel) <= PARAMS.limits.max_rotor_accel * (1 + 1e-12))
        assert np.all(out.gimbal_rate == 0.0)  # D₁ = 0: the gimbals can do nothing
    np.testing.assert_allclose(got.rotor_accel, want.rotor_accel, rtol=1e-9, atol=1e-9)
    # the torque delivered is the one the command makes (−Q η̇), never more than asked for
    assert np.all(np.einsum("bi,bi->b", got.torque, torques) >= -1e-15)


def test_the_damping_is_nil_wherever_the_array_has_authority():
    """At the rotors' nominal speed — far from, near, and at a CMG singularity — the solve is the plain
    weighted pseudo-inverse: never damped, the torque delivered exactly."""
    steer = VscmgSteering(PARAMS)
    rng = np.random.default_rng(6)
    gam = rng.uniform(-np.pi, np.pi, (64, 4))
    gam[:16] = SINGULAR_GIMBALS + 1e-4 * rng.normal(size=(16, 4))
    torque = rng.normal(size=(64, 3)) * 1e-5
    out = steer.solve(torque, gam, np.tile(W0, (64, 1)), 0.02)
    assert not np.any(out.saturation & Saturation.DAMPED)
    free = out.saturation == 0
    np.testing.assert_allclose(out.torque[free], torque[free], rtol=1e-9, atol=1e-15)


@settings(max_examples=60, deadline=None)
@given(
    gimbals=st.lists(st.floats(-7.0, 7.0), min_size=4, max_size=4),
    speeds=st.lists(st.sampled_from([0.0, 1e-9, 1.0, 150.0, 400.0, 900.0]) | st.floats(0.0, 1000.0),
                    min_size=4, max_size=4),
    torque=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    null_gain=st.sampled_from([0.0, 0.5]),
)  # fmt: skip
def test_no_state_of_the_array_makes_steering_raise(gimbals, speeds, torque, null_gain):
    """Any gimbal angles, rotor speeds from stopped to beyond their limits, any torque: a finite command
    within every limit, from the kernel and from its reference alike."""
    from hil.control import steering_reference as ref

    steer = VscmgSteering(PARAMS, SteeringParams(null_gain=null_gain))
    for out in (steer.solve(torque, gimbals, speeds, 0.02), ref.solve(steer, torque, gimbals, speeds, 0.02)):
        for name in ("gimbal_rate", "rotor_accel", "torque"):
            assert np.all(np.isfinite(getattr(out, name))), name
        assert np.all(np.abs(out.gimbal_rate) <= PARAMS.limits.max_gimbal_rate * (1 + 1e-12))
        assert np.all(np.abs(out.rotor_accel) <= PARAMS.limits.max_rotor_accel * (1 + 1e-12))


@settings(max_examples=300, deadline=None)
@given(
    st.integers(-323, 150),
    st.integers(-323, 150),
    st.lists(st.floats(-1.0, 1.0), min_size=9, max_size=9),
    st.floats(-1.0, 1.0),
)
def test_the_smallest_eigenvalue_is_defined_at_every_scale(scale_exp, deviation_exp, entries, shift):
    """Matrices ``s (c I + d B)`` at any finite scale, ``d`` down to the subnormals: the closed form never
    divides by zero (a kernel's division by zero raises: a tiny deviation from a multiple of the identity
    once made the scale cubed underflow, and a control tick with a rotor 1e-73 rad/s from rest raised
    ZeroDivisionError), and it stays within its error of the eigensolver's wherever that is meaningful."""
    from hil.control.steering import min_eigenvalue_sym3

    b = np.array(entries).reshape(3, 3)
    m = 10.0**scale_exp * (shift * np.eye(3) + 10.0**deviation_exp * (b + b.T))
    if not np.all(np.isfinite(m)):
        return
    got = min_eigenvalue_sym3(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
    assert math.isfinite(got)
    big = float(np.max(np.abs(m)))
    if big > 1e-150:  # above the subnormals, where the eigensolver's products keep their digits
        want = np.linalg.eigvalsh(m / big)[0] * big  # scaled: its own squares overflow above ~1e154
        assert got == pytest.approx(want, abs=1e-7 * big)  # a repeated eigenvalue costs ~half the digits


def test_a_rotor_a_hair_from_rest_is_steered_without_raising():
    """The case Hypothesis found in CI: a rotor 1.75e-73 rad/s from rest, the rest stopped, a torque of
    1 N m asked: a finite, damped command, the same from the batched call and the one-row call."""
    steer = VscmgSteering(PARAMS, SteeringParams(null_gain=0.0))
    gimbal, rotor = [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.754984234593556e-73]
    for torque in ([0.0, 0.0, 1.0], [0.0, 0.0, 1e160]):
        out = steer.solve(torque, gimbal, rotor, 0.02)
        rates, accels, delta = steer.solve_one(torque, gimbal, rotor, 0.02)
        assert np.all(np.isfinite(out.gimbal_rate)) and np.all(np.isfinite(out.rotor_accel))
        assert out.saturation[0] & Saturation.DAMPED
        assert rates == out.gimbal_rate[0].tolist() and accels == out.rotor_accel[0].tolist()


def test_the_smallest_eigenvalue_in_closed_form():
    from hil.control.steering import min_eigenvalue_sym3

    rng = np.random.default_rng(7)
    for _ in range(200):
        a = rng.normal(size=(3, 3))
        m = a @ a.T * 10.0 ** rng.uniform(-12, 2)
        if rng.random() < 0.3:  # rank-deficient, as Q W Qᵀ without authority about an axis
            m = a[:, :2] @ a[:, :2].T
        got = min_eigenvalue_sym3(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
        assert got == pytest.approx(np.linalg.eigvalsh(m)[0], abs=1e-13 * np.trace(m))
    assert min_eigenvalue_sym3(2.0, 0.0, 0.0, 2.0, 0.0, 2.0) == 2.0
    with pytest.raises(ConfigError, match="singular_eps"):
        SteeringParams(singular_eps=0.0)


# --------------------------------------------------------------------------- the kernel vs its reference
@pytest.mark.parametrize("null_gain", [0.0, 1.0])
@pytest.mark.parametrize("preset", ["cubesat_1u", "air_bearing_testbed"])
def test_compiled_solve_equals_the_numpy_reference(preset, null_gain):
    """Random gimbal angles (some at the singular set), rotor speeds (some at their limits) and torques
    (some beyond the limits), B = 64 rows per call: every output of the kernel equals the numpy
    reference's to rounding."""
    from hil import vscmg
    from hil.control import steering_reference as ref

    params = getattr(vscmg, preset)()
    lim = params.limits
    steer = VscmgSteering(params, SteeringParams(null_gain=null_gain))
    rng = np.random.default_rng(11)
    n, rows = params.n_units, 64
    gam = rng.uniform(-np.pi, np.pi, (rows, n))
    if n == 4:
        gam[:8] = SINGULAR_GIMBALS + 1e-3 * rng.normal(size=(8, n))
    w = rng.uniform(lim.min_rotor_speed, lim.max_rotor_speed, (rows, n))
    w[8:16, 0] = lim.max_rotor_speed - 0.01
    w[16:24, 1] = lim.min_rotor_speed + 0.01
    w[24:32] = 0.0  # rotors stopped (a board that has just reset): damped least squares
    w[32:40] = rng.uniform(0.0, 0.05 * lim.min_rotor_speed, (8, n))  # ... and at the damping's edge
    h = params.nominal_wheel_momentum
    torque = rng.normal(size=(rows, 3)) * h * rng.choice([0.1, 1.0, 30.0], size=(rows, 1))
    got = steer.solve(torque, gam, w, 0.02)
    want = ref.solve(steer, torque, gam, w, 0.02)
    # Rows at the damping's edge are ill-conditioned by construction: Q W Qᵀ's entries, summed in another
    # order, and its smallest eigenvalue (closed form vs LAPACK) agree to ~1e-16 of its trace, which the
    # damped solve amplifies by its condition number there; everywhere else: to rounding.
    edge = np.zeros(rows, bool)
    edge[32:40] = True
    for name in ("gimbal_rate", "rotor_accel", "torque", "wheel_weight", "scale"):
        a, b = getattr(got, name), getattr(want, name)
        for rows_, rtol in ((~edge, 1e-9), (edge, 1e-6)):
            np.testing.assert_allclose(a[rows_], b[rows_], rtol=rtol, atol=1e-12 * np.abs(b).max(),
                                       err_msg=name)  # fmt: skip
    np.testing.assert_allclose(got.delta, want.delta, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(got.saturation, want.saturation)
    assert {int(s) for s in got.saturation} > {0, int(Saturation.GIMBAL_RATE)}
    assert np.any(got.saturation & Saturation.DAMPED) and not np.all(got.saturation & Saturation.DAMPED)
    np.testing.assert_allclose(steer.delta_gradient(gam, w), ref.delta_gradient(steer, gam, w), rtol=1e-9,
                               atol=1e-12)  # fmt: skip


def test_compiled_adjugate_equals_the_numpy_reference():
    from hil.control import steering_reference as ref
    from hil.control.steering import adjugate3

    a = np.random.default_rng(12).normal(size=(50, 3, 3))
    got = np.array([np.reshape(adjugate3(*m.ravel().tolist()), (3, 3)) for m in a])
    np.testing.assert_allclose(got, ref.adjugate(a), rtol=0, atol=1e-14)
    np.testing.assert_allclose(got[0] @ a[0], np.linalg.det(a[0]) * np.eye(3), atol=1e-13)

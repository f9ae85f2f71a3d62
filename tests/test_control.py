"""The geometric attitude controller and the eigenaxis slew reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil import so3
from hil.control.attitude import AttitudeController, ControllerGains, EigenaxisSlew, Reference
from protocol.errors import ConfigError

J = np.diag([2.1e-3, 2.3e-3, 2.5e-3])


def _rigid_body(controller, ref_at, R, w, T, h=1e-3, disturbance=(0.0, 0.0, 0.0)):
    """A rigid body whose actuators deliver the controller's torque exactly (so ``J Ω̇ = τ_fb`` plus the
    disturbance), exact exponential attitude updates; returns the final (R, ω) and the error history."""
    errors = []
    J_inv = np.linalg.inv(J)
    for k in range(int(round(T / h))):
        out = controller.update(R, w, ref_at(k * h), h)
        w_next = w + h * J_inv @ (out.feedback + np.asarray(disturbance))
        R = R @ so3.exp(0.5 * h * (w + w_next))
        w = w_next
        errors.append(out.angle)
    return R, w, np.array(errors)


def test_small_errors_obey_the_designed_second_order_response():
    """With K_R = ω_n² J and K_Ω = 2ζω_n J a small error about any axis decays as exp(−ζω_n t)."""
    gains = ControllerGains(natural_frequency=1.0, damping=0.7)
    c = AttitudeController(J, gains)
    theta0 = math.radians(2.0)
    axis = np.array([1.0, -2.0, 2.0]) / 3.0
    R, w, err = _rigid_body(c, lambda t: Reference(np.eye(3)), so3.exp(theta0 * axis), np.zeros(3), 6.0)
    t = np.arange(len(err)) * 1e-3
    wd = math.sqrt(1 - 0.7**2)
    expected = theta0 * np.exp(-0.7 * t) * np.abs(np.cos(wd * t) + 0.7 / wd * np.sin(wd * t))
    assert np.max(np.abs(err - expected)) < 0.02 * theta0


def test_errors_have_no_sign_ambiguity_and_vanish_only_at_the_reference():
    c = AttitudeController(J)
    ref = Reference(so3.exp([0.3, -0.2, 0.1]))
    e_R, _, _ = c.errors(ref.R, np.zeros(3), ref)
    np.testing.assert_allclose(e_R, 0.0, atol=1e-15)
    # e_R points along the rotation from the reference: sin θ times the axis, same for θ and θ − 2π
    for theta in (0.5, 2.5, 3.0):
        R = ref.R @ so3.exp(theta * np.array([0.0, 0.0, 1.0]))
        e_R, _, _ = c.errors(R, np.zeros(3), ref)
        np.testing.assert_allclose(e_R, [0.0, 0.0, math.sin(theta)], atol=1e-12)


def test_large_slew_converges_and_integral_term_removes_a_constant_disturbance():
    gains = ControllerGains(natural_frequency=0.8, damping=0.9, integral_time_s=3.0)
    c = AttitudeController(J, gains)
    target = so3.exp([0.0, 0.0, math.radians(170.0)])
    R, w, err = _rigid_body(c, lambda t: Reference(target), np.eye(3), np.zeros(3), 60.0,
                            h=5e-3, disturbance=np.array([2e-6, -1e-6, 1.5e-6]))  # fmt: skip
    assert err[-1] < math.radians(0.01)
    assert np.linalg.norm(w) < 2e-5


def test_tracking_the_eigenaxis_slew_with_feedforward():
    slew = EigenaxisSlew.within_limits(np.eye(3), so3.exp([0.0, math.pi / 2, 0.0]), 0.15, 0.025)
    assert slew.duration_s == pytest.approx(
        max(1.875 * math.pi / 2 / 0.15, math.sqrt(5.7735 * math.pi / 2 / 0.025))
    )
    # the reference's rate is the derivative of its attitude, and it starts and ends at rest
    t, dt = 7.3, 1e-5
    a, b = slew.at(t), slew.at(t + dt)
    np.testing.assert_allclose(so3.log(a.R.T @ b.R) / dt, a.omega, rtol=1e-4)
    np.testing.assert_allclose(slew.at(0.0).omega, 0.0)
    np.testing.assert_allclose(slew.at(slew.duration_s).R, so3.exp([0.0, math.pi / 2, 0.0]), atol=1e-12)
    peak = max(np.linalg.norm(slew.at(x).omega) for x in np.linspace(0, slew.duration_s, 401))
    assert peak <= 0.15 + 1e-9
    c = AttitudeController(J, ControllerGains(0.5, 0.9))
    R, _, err = _rigid_body(c, slew.at, np.eye(3), np.zeros(3), slew.duration_s, h=5e-3)
    assert max(err) < math.radians(0.05)  # with feedforward the body stays on the moving reference
    assert so3.angle_between(R, so3.exp([0.0, math.pi / 2, 0.0])) < math.radians(0.05)


def test_controller_output_includes_gyroscopic_terms_for_the_array():
    c = AttitudeController(J)
    w = np.array([0.1, -0.05, 0.02])
    h = np.array([1e-3, 2e-3, -1e-3])
    out = c.update(np.eye(3), w, Reference(np.eye(3), omega=w), 0.0, h)
    np.testing.assert_allclose(out.torque - out.feedback, np.cross(w, J @ w + h), rtol=1e-12)


def test_the_float_control_law_matches_its_numpy_form():
    """update() and the slew's reference run on Python floats; the law written in numpy (the module
    docstring's equations) gives the same outputs to rounding, integral term and distinct weights included."""
    rng = np.random.default_rng(7)
    Jf = np.array([[2.1e-3, 1e-4, -5e-5], [1e-4, 2.3e-3, 2e-4], [-5e-5, 2e-4, 2.5e-3]])
    gains = ControllerGains(0.7, 0.9, weights=(1.0, 1.4, 0.6), integral_time_s=2.0, integral_limit=0.02)
    c = AttitudeController(Jf, gains)
    K, K_R, K_O = np.diag(gains.weights), 0.49 * Jf, 2 * 0.9 * 0.7 * Jf
    integral = np.zeros(3)
    for _ in range(200):
        R, Rd = so3.exp(rng.normal(size=3)), so3.exp(rng.normal(size=3))
        w, h = rng.normal(size=3) * 0.2, rng.normal(size=3) * 1e-3
        ref = Reference(Rd, rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.01)
        out = c.update(R, w, ref, 0.05, h)
        m = R.T @ Rd
        e_R = 0.5 * so3.vee(K @ m.T - m @ K)
        e_w = w - m @ ref.omega
        integral = np.clip(integral + 0.05 * e_R, -0.02, 0.02)
        fb = -K_R @ e_R - K_O @ e_w - K_R @ integral / 2.0
        fb += Jf @ (m @ ref.omega_dot - np.cross(w, m @ ref.omega))
        for got, want in ((out.e_R, e_R), (out.e_omega, e_w), (c.integral, integral), (out.feedback, fb),
                          (out.torque, fb + np.cross(w, Jf @ w + h))):  # fmt: skip
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15 * np.abs(want).max())
        assert out.angle == pytest.approx(so3.principal_angle(m), rel=1e-14, abs=1e-15)
    slew = EigenaxisSlew.within_limits(np.eye(3), so3.exp([0.3, -1.2, 0.5]), 0.15, 0.025, start_s=1.0)
    phi = so3.log(so3.exp([0.3, -1.2, 0.5]))
    for t in np.linspace(0.0, slew.duration_s + 2.0, 23):
        tau = min(max((t - 1.0) / slew.duration_s, 0.0), 1.0)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        np.testing.assert_allclose(slew.at(t).R, so3.exp(s * phi), rtol=0, atol=1e-15)


def test_bad_gains_and_inertia_are_refused():
    with pytest.raises(ConfigError, match="natural_frequency"):
        ControllerGains(natural_frequency=0.0)
    with pytest.raises(ConfigError, match="weights"):
        ControllerGains(weights=(1.0, -1.0, 1.0))
    with pytest.raises(ConfigError, match="inertia"):
        AttitudeController(np.diag([1e-3, -1e-3, 1e-3]))
    with pytest.raises(ConfigError):
        EigenaxisSlew.within_limits(np.eye(3), np.eye(3), 0.0, 1.0)

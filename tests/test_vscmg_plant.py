"""The VSCMG plant against its invariants, an analytic case, its convergence order, and an independent
implementation of Schaub & Junkins' classical VSCMG equations (σ = 0, axisymmetric rotors)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from firmware_sim.world.models import GravityGradient, Plant
from hil import so3
from hil.vscmg import (
    UnitParams,
    air_bearing_testbed,
    cubesat_1u,
    custom_array,
    pyramid,
)
from protocol.errors import ConfigError, NumericalError


def _spinning(plant: Plant, batch: int = 1):
    rng = np.random.default_rng(7)
    n = plant.n
    return plant.state(
        R=so3.exp(rng.normal(size=3)),
        omega=rng.normal(0.0, 0.05, (batch, 3)),
        gimbal_angle=rng.uniform(-1.0, 1.0, (batch, n)),
        gimbal_rate=rng.normal(0.0, 0.3, (batch, n)),
        rotor_rate=rng.uniform(300.0, 500.0, (batch, n)),
    )


def _servo_law(plant: Plant):
    """Motor torques that keep working: gimbal rate servos tracking a sinusoid, rotors pushed around."""
    lim = plant.params.limits

    def law(t, gimbal_angle, gimbal_rate, rotor_rate, gimbal_load, rotor_load):
        target = 0.8 * np.sin(0.7 * t + np.arange(plant.n))
        ug = np.clip(2e-4 * (target - gimbal_rate), -lim.max_gimbal_torque, lim.max_gimbal_torque)
        us = 2e-4 * np.cos(0.5 * t + np.arange(plant.n)) + 1e-6 * (400.0 - rotor_rate)
        return ug, us

    return law


def _relative(a, b):
    return float(np.max(np.linalg.norm(a - b, axis=-1) / np.linalg.norm(b, axis=-1)))


def test_momentum_conserved_over_100_s_with_motor_torques_active():
    """Inertial angular momentum, recomputed body by body from (R, Ω, γ̇, φ̇), stays put over 100 s while
    gimbal servos and rotor motors work, for the 1U pyramid and the testbed tetrahedron.

    The step is 10 ms, not 1 ms, to keep the test fast: the integrator advances π exactly (π̇ = 0 without
    external moments), so momentum conservation does not depend on the step; this checks that the
    velocities the mass-matrix solve returns carry exactly that momentum, every step. The 1 ms energy test
    below covers accuracy."""
    for params, duration in ((cubesat_1u(), 100.0), (air_bearing_testbed(), 10.0)):
        plant = Plant(params)
        s = _spinning(plant)
        pi0 = plant.angular_momentum(s)
        e0 = plant.kinetic_energy(s)
        worst = 0.0
        for _ in range(int(duration)):
            s = plant.run(s, 1e-2, 100, _servo_law(plant))
            worst = max(worst, _relative(plant.angular_momentum(s), pi0))
        assert s.t == pytest.approx(duration)
        assert worst <= 1e-8, params
        assert abs(plant.kinetic_energy(s)[0] - e0[0]) > 1e-3 * e0[0]  # the motors did change the energy
        assert so3.orthonormality_error(s.R[0]) < 1e-12


def test_energy_and_momentum_conserved_without_motor_torques_at_1_ms():
    plant = Plant(cubesat_1u())
    s = _spinning(plant)
    e0, pi0 = plant.kinetic_energy(s), plant.angular_momentum(s)
    s = plant.run(s, 1e-3, 3000)
    assert abs(plant.kinetic_energy(s)[0] - e0[0]) / e0[0] < 1e-9
    assert _relative(plant.angular_momentum(s), pi0) < 1e-12
    assert np.max(np.abs(s.gimbal_angle - _spinning(plant).gimbal_angle)) > 0.1  # free gimbals did move


def test_work_of_the_motors_equals_the_change_of_energy():
    """dT/dt = Σ u_g γ̇ + u_s φ̇: the motor power integrated along the run matches the energy change."""
    plant = Plant(cubesat_1u())
    law = _servo_law(plant)
    s = _spinning(plant)
    e0 = plant.kinetic_energy(s)[0]
    h, work = 1e-3, 0.0

    def power(state):
        ug, us = law(state.t, state.gimbal_angle, state.gimbal_rate, state.rotor_rate, None, None)
        return float(np.sum(ug * state.gimbal_rate + us * state.rotor_rate))

    p_prev = power(s)
    for _ in range(1000):
        s = plant.step(s, h, law)
        p = power(s)
        work += 0.5 * h * (p + p_prev)  # trapezoid: O(h²) against the O(h⁴) plant
        p_prev = p
    de = plant.kinetic_energy(s)[0] - e0
    assert abs(de) > 1e-6
    assert de == pytest.approx(work, rel=1e-5)


def test_non_axisymmetric_rotor_with_offset_conserves_energy_at_its_suggested_step():
    unit = UnitParams(
        gimbal_axis=(0, 0, 1),
        spin_axis=(1, 0, 0),
        rotor_inertia=((1.0e-5, 2e-7, 0.0), (2e-7, 5.2e-6, 1e-7), (0.0, 1e-7, 5.9e-6)),
        gimbal_inertia=((1.5e-6, 1e-7, 0), (1e-7, 1.7e-6, 0), (0, 0, 2e-6)),
        rotor_offset_m=2e-3,
    )
    params = replace(cubesat_1u(), units=pyramid(4, radius_m=0.025, template=unit))
    plant = Plant(params)
    s = _spinning(plant)
    h = plant.suggested_step(s)
    assert h < 3e-4
    e0, pi0 = plant.kinetic_energy(s), plant.angular_momentum(s)
    s = plant.run(s, h, int(0.3 / h))
    assert abs(plant.kinetic_energy(s)[0] - e0[0]) / e0[0] < 1e-8
    assert _relative(plant.angular_momentum(s), pi0) < 1e-12


def test_batch_equals_single_runs():
    plant = Plant(cubesat_1u())
    batch = _spinning(plant, batch=3)
    law = _servo_law(plant)
    out = plant.run(batch, 1e-3, 200, law)
    for i in range(3):
        single = plant.run(plant.select(batch, i), 1e-3, 200, law)
        np.testing.assert_allclose(single.omega[0], out.omega[i], rtol=0, atol=1e-13)
        np.testing.assert_allclose(single.rotor_rate[0], out.rotor_rate[i], rtol=1e-13)
        np.testing.assert_allclose(single.R[0], out.R[i], rtol=0, atol=1e-13)


def test_per_run_parameters_on_the_batch_axis_equal_each_run_alone():
    """A batch whose runs carry their own spacecraft (dispersed bus inertia, a non-axisymmetric rotor with
    a larger offset σ, a misaligned unit) steps exactly as each run does on its own plant, and each run
    conserves its own momentum."""
    base = cubesat_1u()
    units = list(base.units)
    tilt = so3.exp([0.01, -0.02, 0.0])
    units[1] = replace(
        units[1], gimbal_axis=tuple(tilt @ units[1].gimbal_axis), spin_axis=tuple(tilt @ units[1].spin_axis)
    )
    runs = [
        base,
        replace(base, bus_inertia=(2.3e-3, 1.9e-3, 2.4e-3)),
        replace(base, units=tuple(units)),
        cubesat_1u(rotor_offset_m=2e-3),
    ]
    runs[3] = replace(
        runs[3], units=(replace(runs[3].units[0], rotor_inertia=(1e-5, 5.0e-6, 6.0e-6)),) + runs[3].units[1:]
    )
    plant = Plant(runs)
    assert plant.model.batch == 4 and not plant.model.axisymmetric
    batch = _spinning(Plant(base), batch=4)
    batch = plant.state(
        R=batch.R, omega=batch.omega, gimbal_angle=batch.gimbal_angle, gimbal_rate=batch.gimbal_rate,
        rotor_rate=batch.rotor_rate,
    )  # fmt: skip
    pi0 = plant.angular_momentum(batch)
    law = _servo_law(plant)
    out = plant.run(batch, 2e-4, 100, law)
    np.testing.assert_allclose(plant.angular_momentum(out), pi0, rtol=1e-11, atol=1e-16)
    for i, params in enumerate(runs):
        alone = Plant(params)
        start = alone.state(
            R=batch.R[i], omega=batch.omega[i], gimbal_angle=batch.gimbal_angle[i],
            gimbal_rate=batch.gimbal_rate[i], rotor_rate=batch.rotor_rate[i],
        )  # fmt: skip
        single = alone.run(start, 2e-4, 100, law)
        np.testing.assert_allclose(single.omega[0], out.omega[i], rtol=0, atol=1e-13)
        np.testing.assert_allclose(single.gimbal_rate[0], out.gimbal_rate[i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(single.R[0], out.R[i], rtol=0, atol=1e-13)
        np.testing.assert_allclose(
            alone.kinetic_energy(single), plant.kinetic_energy(out)[i : i + 1], rtol=1e-12
        )
    assert not np.allclose(out.omega[0], out.omega[1])  # the dispersed runs really moved differently
    with pytest.raises(ConfigError, match="4 runs, not 2"):
        plant.state(gimbal_angle=np.zeros((2, 4)))
    with pytest.raises(ConfigError, match="4 runs, not 1"):
        plant.step(plant.select(out, 0), 1e-3)
    with pytest.raises(ConfigError, match="same number of units"):
        Plant([base, air_bearing_testbed()])


def test_single_axis_rotor_spin_up_matches_the_analytic_solution():
    """One rotor along the body's principal z axis, gimbal axis x held by symmetry, body at rest: a
    constant rotor torque u spins the body the other way, Ω = −I_s φ̇ / J_zz with
    φ̈ = u / (I_s (1 − I_s/J_zz)) (J_zz the locked inertia about z)."""
    unit = UnitParams(
        gimbal_axis=(1, 0, 0),
        spin_axis=(0, 0, 1),
        rotor_inertia=(1e-5, 6e-6, 6e-6),
        gimbal_inertia=(1e-6, 1e-6, 1e-6),
    )
    params = replace(cubesat_1u(), bus_inertia=(2e-3, 2.1e-3, 2.2e-3), units=(unit,))
    plant = Plant(params)
    s = plant.state(rotor_rate=0.0, omega=0.0)
    jzz = plant.locked_inertia(s)[0, 2, 2]
    u, T = 1e-4, 2.0
    s = plant.run(s, 1e-3, 2000, ((0.0,), (u,)))
    phidot = u * T / (1e-5 * (1.0 - 1e-5 / jzz))
    assert s.rotor_rate[0, 0] == pytest.approx(phidot, rel=1e-12)
    np.testing.assert_allclose(s.omega[0], [0.0, 0.0, -1e-5 * phidot / jzz], atol=1e-15)
    yaw = -1e-5 * phidot / jzz * T / 2.0
    np.testing.assert_allclose(s.R[0], so3.exp([0.0, 0.0, yaw]), atol=1e-12)


def test_fourth_order_convergence():
    plant = Plant(cubesat_1u())
    law = _servo_law(plant)
    s0 = _spinning(plant)

    def final(h):
        s = plant.run(s0, h, int(round(0.2 / h)), law)
        return np.concatenate([s.omega[0], s.gimbal_rate[0], s.rotor_rate[0] * 1e-3, so3.log(s.R[0])])

    ref = final(0.25e-3)
    e1 = np.linalg.norm(final(4e-3) - ref)
    e2 = np.linalg.norm(final(2e-3) - ref)
    assert 12.0 < e1 / e2 < 20.0, (e1, e2)


# --------------------------------------------------------------------------- Schaub–Junkins reduction
def _schaub_junkins_rhs(I_s, units, L):
    """The classical VSCMG equations (Schaub & Junkins, Analytical Mechanics of Space Systems, VSCMG
    section) for axisymmetric, σ = 0 units: state (q (4, scalar first), ω, γ, γ̇, Ω_w)."""
    n = len(units)
    g = np.array([u.gimbal_axis for u in units], float)
    s0 = np.array([u.spin_axis for u in units], float)
    t0 = np.cross(g, s0)
    IG = np.array(
        [np.diag(u.gimbal_inertia) if np.ndim(u.gimbal_inertia) == 2 else u.gimbal_inertia for u in units]
    )
    IW = np.array([u.rotor_inertia for u in units], float)
    Js, Jt, Jg = IG[:, 0] + IW[:, 0], IG[:, 1] + IW[:, 1], IG[:, 2] + IW[:, 2]
    Iws = IW[:, 0]

    def rhs(_t, y):
        q, w = y[:4], y[4:7]
        gam, gd, Om = y[7 : 7 + n], y[7 + n : 7 + 2 * n], y[7 + 2 * n :]
        gs = np.cos(gam)[:, None] * s0 + np.sin(gam)[:, None] * t0
        gt = np.cos(gam)[:, None] * t0 - np.sin(gam)[:, None] * s0
        ws, wt, wg = gs @ w, gt @ w, g @ w
        I = I_s + sum(
            Js[i] * np.outer(gs[i], gs[i]) + Jt[i] * np.outer(gt[i], gt[i]) + Jg[i] * np.outer(g[i], g[i])
            for i in range(n)
        )
        # unknowns: ω̇ (3), γ̈ (n), Ω̇ (n)
        A = np.zeros((3 + 2 * n, 3 + 2 * n))
        b = np.zeros(3 + 2 * n)
        A[:3, :3] = I
        b[:3] = -np.cross(w, I @ w) + L
        for i in range(n):
            A[:3, 3 + i] = Jg[i] * g[i]
            A[:3, 3 + n + i] = Iws[i] * gs[i]
            b[:3] -= gs[i] * (Js[i] * gd[i] * wt[i] - (Jt[i] - Jg[i]) * wt[i] * gd[i])
            b[:3] -= gt[i] * (
                (Js[i] * ws[i] + Iws[i] * Om[i]) * gd[i]
                - (Jt[i] + Jg[i]) * ws[i] * gd[i]
                + Iws[i] * Om[i] * wg[i]
            )
            b[:3] += g[i] * (Iws[i] * Om[i] * wt[i])
            # gimbal: J_g (γ̈ + g·ω̇) = u_g + (J_s − J_t) ω_s ω_t + I_Ws Ω ω_t   (u_g = 0)
            A[3 + i, :3] = Jg[i] * g[i]
            A[3 + i, 3 + i] = Jg[i]
            b[3 + i] = (Js[i] - Jt[i]) * ws[i] * wt[i] + Iws[i] * Om[i] * wt[i]
            # wheel: I_Ws (Ω̇ + g_s·ω̇ + γ̇ ω_t) = u_s   (u_s = 0)
            A[3 + n + i, :3] = Iws[i] * gs[i]
            A[3 + n + i, 3 + n + i] = Iws[i]
            b[3 + n + i] = -Iws[i] * gd[i] * wt[i]
        acc = np.linalg.solve(A, b)
        qdot = 0.5 * np.array([-q[1:] @ w, *(q[0] * w + np.cross(q[1:], w))])
        return np.concatenate([qdot, acc[:3], gd, acc[3 : 3 + n], acc[3 + n :]])

    return rhs


def test_reduces_to_the_classical_schaub_junkins_model():
    """σ = 0, axisymmetric rotors and diagonal gimbal inertias: trajectories agree with an independent
    integration (DOP853, quaternions) of the classical equations over 3 s of free motion."""
    unit = UnitParams(
        gimbal_axis=(0, 0, 1),
        spin_axis=(1, 0, 0),
        gimbal_inertia=(1.5e-6, 1.8e-6, 2.0e-6),
        rotor_inertia=(1.0e-5, 5.5e-6, 5.5e-6),
        rotor_offset_m=0.0,
    )
    params = replace(cubesat_1u(), units=pyramid(4, radius_m=0.025, height_m=-0.02, template=unit))
    plant = Plant(params)
    s = _spinning(plant)
    I_s = plant.model.J0  # bus plus every body's parallel-axis term: S&J's [I_s]
    q0 = so3.matrix_to_quat(s.R[0])
    y0 = np.concatenate([q0, s.omega[0], s.gimbal_angle[0], s.gimbal_rate[0], s.rotor_rate[0]])
    T = 1.5
    sol = solve_ivp(
        _schaub_junkins_rhs(I_s, params.units, np.zeros(3)),
        (0, T),
        y0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-13,
    )
    assert sol.success
    y = sol.y[:, -1]
    n = plant.n

    def error(h):
        out = plant.run(s, h, int(round(T / h)))
        return out, max(
            float(np.max(np.abs(out.omega[0] - y[4:7]))),
            float(np.max(np.abs(out.gimbal_rate[0] - y[7 + n : 7 + 2 * n]))) * 1e-2,
            float(np.max(np.abs(out.rotor_rate[0] - y[7 + 2 * n :]))) * 1e-3,
            so3.angle_between(out.R[0], so3.quat_to_matrix(y[:4])),
        )

    # free gimbals nutate at ~50 rad/s here; at 1 ms the difference is the integrator's O(h⁴) error, and
    # it shrinks 16-fold per halving of the step: the two models are the same
    _, e_coarse = error(1e-3)
    out, e_fine = error(5e-4)
    assert e_fine < 5e-8
    assert e_coarse / e_fine > 12.0
    np.testing.assert_allclose(out.gimbal_angle[0], y[7 : 7 + n], rtol=0, atol=1e-8)
    # the motion is not trivial: the gimbals and body did move
    assert np.max(np.abs(out.gimbal_angle[0] - s.gimbal_angle[0])) > 0.05


def test_offset_sigma_only_adds_a_constant_parallel_axis_inertia():
    base = cubesat_1u(rotor_offset_m=0.0)
    shifted = cubesat_1u(rotor_offset_m=3e-3)
    d = Plant(shifted).model.J0 - Plant(base).model.J0
    assert np.max(np.abs(d)) > 1e-8
    np.testing.assert_allclose(d, d.T, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(d) > -1e-15)  # moving mass away from the centre never lowers inertia


# --------------------------------------------------------------------------- gravity gradient
def test_gravity_gradient_torque_and_momentum_exchange():
    gg = GravityGradient.circular(500e3)
    assert gg.mean_motion == pytest.approx(1.1068e-3, rel=1e-3)
    plant = Plant(cubesat_1u(), gravity=gg)
    J = plant.locked_inertia(plant.state())
    # a principal axis along the radial direction feels no moment
    _, vecs = np.linalg.eigh(J[0])
    R_principal = np.linalg.inv(vecs)  # body principal axes to inertial x, y, z
    R_principal = so3.project(R_principal if np.linalg.det(R_principal) > 0 else -R_principal)
    np.testing.assert_allclose(gg.torque(0.0, R_principal[None], J), 0.0, atol=1e-18)
    tilted = so3.exp([0.0, 0.0, 0.3])[None]
    tau = gg.torque(0.0, tilted, J)
    assert np.linalg.norm(tau) > 1e-12
    # momentum changes at R τ
    s = plant.state(R=tilted[0], rotor_rate=400.0)
    s1 = plant.run(s, 1e-3, 100)
    dpi = plant.angular_momentum(s1) - plant.angular_momentum(s)
    np.testing.assert_allclose(dpi[0], 0.1 * (tilted[0] @ tau[0]), rtol=1e-2, atol=1e-16)


# --------------------------------------------------------------------------- bad input
def test_bad_parameters_and_inputs_raise_typed_errors():
    with pytest.raises(ConfigError, match="gimbal_axis"):
        UnitParams(gimbal_axis=(0, 0, 2), spin_axis=(1, 0, 0))
    with pytest.raises(ConfigError, match="perpendicular"):
        UnitParams(gimbal_axis=(0, 0, 1), spin_axis=(0, 0.6, 0.8))
    with pytest.raises(ConfigError, match="triangle"):
        UnitParams(gimbal_axis=(0, 0, 1), spin_axis=(1, 0, 0), rotor_inertia=(1e-5, 1e-6, 1e-6))
    with pytest.raises(ConfigError, match="unit 1"):
        custom_array([[0, 0, 1], [0, 0, 1]], [[1, 0, 0], [0, 0, 1]])
    plant = Plant(cubesat_1u())
    with pytest.raises(ConfigError, match="omega"):
        plant.state(omega=(np.nan, 0, 0))
    s = plant.state()
    with pytest.raises(NumericalError, match="non-finite motor torque"):
        plant.step(s, 1e-3, ((np.nan, 0, 0, 0), 0.0))
    with pytest.raises(ConfigError, match="dt"):
        plant.step(s, -1e-3)

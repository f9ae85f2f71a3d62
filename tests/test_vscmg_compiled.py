"""The compiled plant (firmware_sim.world.models.compiled, its kernels and the drive law of .drives) against
the numpy Plant and ServoModel as the references: the same states to rounding over thousands of steps from
random states (both presets, axisymmetric, non-axisymmetric and g-coupled gimbal inertias, rotor offset σ,
gravity gradient; no, constant and servo torques, gimbals on rates and on angles, undriven rotors), the
plant's invariants on the compiled plant (momentum, energy, the motors' work), and its errors."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields, replace

import numpy as np
import pytest

from firmware_sim.world.models import CompiledPlant, Drive, GravityGradient, Plant, ServoModel
from firmware_sim.world.models.drives import drive_torques
from hil import so3
from hil.control.motor_loops import ServoParams, Setpoints
from hil.vscmg import (
    PlantState,
    SpacecraftParams,
    UnitParams,
    air_bearing_testbed,
    cubesat_1u,
    pyramid,
)
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError, NumericalError

FIELDS = tuple(f.name for f in fields(PlantState) if f.name != "t")  # every array of the state
PRESETS: dict[str, Callable[[], SpacecraftParams]] = {
    "cubesat_1u": cubesat_1u,
    "air_bearing_testbed": air_bearing_testbed,
}


def _non_axisymmetric(params: SpacecraftParams) -> SpacecraftParams:
    """Every rotor with unequal transverse moments and a dynamic imbalance (products of inertia)."""
    units = []
    for u in params.units:
        a, b, c = np.diag(inertia_tensor(u.rotor_inertia, "rotor_inertia"))
        iw = ((a, 0.02 * a, -0.01 * a), (0.02 * a, 0.97 * b, 0.01 * b), (-0.01 * a, 0.01 * b, 1.05 * c))
        units.append(replace(u, rotor_inertia=iw))
    return replace(params, units=tuple(units))


def _coupled_gimbals(params: SpacecraftParams) -> SpacecraftParams:
    """Every gimbal structure with products of inertia, some coupling the gimbal axis to s and t."""
    units = []
    for u in params.units:
        a, b, c = np.diag(inertia_tensor(u.gimbal_inertia, "gimbal_inertia"))
        ig = ((a, 0.05 * a, 0.08 * a), (0.05 * a, b, -0.06 * b), (0.08 * a, -0.06 * b, c))
        units.append(replace(u, gimbal_inertia=ig))
    return replace(params, units=tuple(units))


def _params(preset: str, rotor: str) -> SpacecraftParams:
    p = PRESETS[preset]()
    assert all(u.rotor_offset_m != 0.0 for u in p.units)  # σ ≠ 0 in both presets
    if rotor == "coupled-gimbal":
        return _coupled_gimbals(p)
    return p if rotor == "axisymmetric" else _non_axisymmetric(p)


def _random_state(plant: Plant, seed: int) -> PlantState:
    rng = np.random.default_rng(seed)
    n = plant.n
    return plant.state(
        R=so3.exp(rng.normal(size=3)),
        omega=rng.normal(0.0, 0.05, 3),
        gimbal_angle=rng.uniform(-1.0, 1.0, n),
        gimbal_rate=rng.normal(0.0, 0.3, n),
        rotor_rate=rng.uniform(300.0, 500.0, n),
        rotor_angle=rng.uniform(0.0, 6.0, n),
        t=rng.uniform(0.0, 5.0),
    )


def _servo(params: SpacecraftParams, coast: float | None = None, modes: bool = False) -> ServoModel:
    """Servos holding non-trivial setpoints: gimbals turning both ways, rotors pushed up and down (an ESC
    that cannot brake with ``coast``); with ``modes`` one gimbal on an angle and one rotor undriven."""
    servo = ServoModel(params, ServoParams(coast_time_constant_s=coast, load_rejection=0.8))
    n = len(params.units)
    gimbal = np.array([[0.4, -0.3, 0.2, -0.1][:n]])
    rotor = np.array([[520.0, 280.0, 450.0, 350.0][:n]])
    if modes:
        angle = np.full((1, n), np.nan)
        angle[0, 1] = 2.5  # far: the position loop saturates at the rate limit, then closes in
        undriven = np.zeros((1, n), bool)
        undriven[0, n - 1] = True
        servo.hold(Setpoints(gimbal, rotor, np.zeros(1, bool)), angle_target=angle, rotor_undriven=undriven)
    else:
        servo.hold(Setpoints(gimbal, rotor, np.zeros(1, bool)))
    return servo


def _assert_same(fast: PlantState, ref: PlantState, rtol: float = 1e-10) -> None:
    assert fast.t == pytest.approx(ref.t, rel=1e-15)
    for name in FIELDS:
        a, b = getattr(fast, name), getattr(ref, name)
        assert a.shape == b.shape, name
        scale = float(np.max(np.abs(b)))
        err = float(np.max(np.abs(a - b)))
        assert err <= rtol * scale, (name, err, scale)


def _both(plant: Plant, start: PlantState, steps: int, torques, h: float = 1e-3):
    """``steps`` steps on the numpy plant and, in one compiled call, on the compiled plant."""
    ref = start
    for _ in range(steps):
        ref = plant.step(ref, h, torques)
    return CompiledPlant(plant).run(start, h, steps, torques), ref


# --------------------------------------------------------------------------- against the reference
CASES = [
    (preset, rotor, torques)
    for preset in PRESETS
    for rotor in ("axisymmetric", "non-axisymmetric", "coupled-gimbal")
    for torques in ("servo", "none")
    if not (rotor == "coupled-gimbal" and torques == "none")
]


@pytest.mark.parametrize(("preset", "rotor", "torques"), CASES)
def test_2000_steps_equal_the_numpy_plant_and_keep_its_invariants(preset, rotor, torques):
    params = _params(preset, rotor)
    plant = Plant(params)
    assert plant.model.axisymmetric == (rotor != "non-axisymmetric")
    start = _random_state(plant, 11)
    law = _servo(params, coast=0.6) if torques == "servo" else None
    fast, ref = _both(plant, start, 2000, law)
    _assert_same(fast, ref)
    # the motion was not trivial: gimbals and rotors moved, the servos did work (or none did)
    assert np.max(np.abs(fast.gimbal_angle - start.gimbal_angle)) > 0.05
    pi0, e0 = plant.angular_momentum(start)[0], plant.kinetic_energy(start)[0]
    pi, e = plant.angular_momentum(fast)[0], plant.kinetic_energy(fast)[0]
    assert np.linalg.norm(pi - pi0) <= 1e-11 * np.linalg.norm(pi0)  # internal torques never make momentum
    if law is None and rotor != "non-axisymmetric":
        assert abs(e - e0) <= 1e-9 * e0  # free, and 1 ms resolves the axisymmetric plant
    elif law is not None:
        assert abs(e - e0) > 1e-4 * e0  # the motors did change the energy
    assert so3.orthonormality_error(fast.R[0]) < 1e-13


@pytest.mark.parametrize("seed", range(6))
def test_random_states_one_step_and_a_hundred_equal_the_numpy_plant(seed):
    """Random states and spacecraft (preset, rotor kind), with servo drives on rates and angles and an
    undriven rotor, one step of 1 ms and then a hundred."""
    rng = np.random.default_rng(100 + seed)
    params = _params(
        ("cubesat_1u", "air_bearing_testbed")[seed % 2],
        ("axisymmetric", "non-axisymmetric", "coupled-gimbal")[seed % 3],
    )
    plant = Plant(params)
    start = _random_state(plant, seed)
    law = _servo(params, coast=float(rng.choice([0.5, 2.0])), modes=True)
    c = CompiledPlant(plant)
    _assert_same(c.step_state(start, 1e-3, law), plant.step(start, 1e-3, law), rtol=1e-13)
    fast, ref = _both(plant, start, 100, law)
    _assert_same(fast, ref, rtol=1e-12)


@pytest.mark.parametrize("rotor", ["axisymmetric", "non-axisymmetric", "coupled-gimbal"])
def test_gravity_gradient_with_servos_equals_the_numpy_plant(rotor):
    params = _params("cubesat_1u", rotor)
    # a low orbit whose moment is visible in 2 s: π changes, by R τ
    plant = Plant(params, gravity=GravityGradient(mean_motion=0.05, orbit_normal=(0.0, 0.6, 0.8)))
    start = _random_state(plant, 12)
    fast, ref = _both(plant, start, 2000, _servo(params))
    _assert_same(fast, ref)
    moved = np.linalg.norm(fast.momentum[0] - start.momentum[0]) / np.linalg.norm(start.momentum[0])
    assert moved > 1e-4  # the gravity gradient did exchange momentum with the orbit


def test_constant_torques_and_per_run_parameters_of_one_run_equal_the_numpy_plant():
    params = _non_axisymmetric(cubesat_1u())
    plant = Plant([params])  # per-run parameters, a batch of one
    assert plant.model.batch == 1
    start = _random_state(plant, 13)
    constant = ([2e-5, -1e-5, 1.5e-5, -2e-5], 3e-5)  # a per-unit gimbal torque, one rotor torque for all
    fast, ref = _both(plant, start, 500, constant)
    _assert_same(fast, ref)
    same = CompiledPlant(plant).run(start, 1e-3, 500, Drive.constant(*constant, n=4))
    _assert_same(same, fast, rtol=0.0)


def test_state_conversions_views_and_observed_runs():
    plant = Plant(_non_axisymmetric(air_bearing_testbed()))
    c = CompiledPlant(plant)
    s = _random_state(plant, 14)
    flat = c.pack(s)
    assert flat.shape == (c.size,) and flat.dtype == np.float64
    back = c.unpack(flat)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(s, name))
    assert back.t == s.t
    np.testing.assert_array_equal(c.R_of(flat), s.R[0])
    np.testing.assert_array_equal(c.omega_of(flat), s.omega[0])
    np.testing.assert_array_equal(c.gimbal_angle_of(flat), s.gimbal_angle[0])
    np.testing.assert_array_equal(c.gimbal_rate_of(flat), s.gimbal_rate[0])
    np.testing.assert_array_equal(c.rotor_rate_of(flat), s.rotor_rate[0])
    # advancing in place, the path recorded; an observed run sees every state
    law = _servo(plant.params)
    path = np.zeros((21, 13))
    c.advance(flat, 1e-3, 20, law, path)
    seen: list[PlantState] = []
    out = c.run(s, 1e-3, 20, law, observe=seen.append)
    assert len(seen) == 20
    _assert_same(c.unpack(flat), out, rtol=0.0)
    np.testing.assert_array_equal(path[0], np.concatenate([[s.t], s.R[0].ravel(), s.omega[0]]))
    for row, state in zip(path[1:], seen, strict=True):
        np.testing.assert_array_equal(row, np.concatenate([[state.t], state.R[0].ravel(), state.omega[0]]))
    one = c.step(c.pack(s), 1e-3, law)
    _assert_same(c.unpack(one), seen[0], rtol=0.0)


# --------------------------------------------------------------------------- the drive law
@pytest.mark.parametrize("coast", [None, 0.8])
def test_drive_law_kernel_is_what_the_servo_model_computes(coast):
    params = cubesat_1u()
    lim = params.limits
    rng = np.random.default_rng(3)
    ug, us = np.zeros(4), np.zeros(4)
    for k in range(300):
        servo = _servo(params, coast=coast, modes=k % 2 == 1)
        ga = rng.uniform(-7.0, 7.0, (1, 4))  # angles beyond ±π: the position loop wraps the error
        gr = rng.normal(0.0, 1.0, (1, 4))
        wr = rng.uniform(200.0, 600.0, (1, 4))
        fg = rng.normal(0.0, 3.0 * lim.max_gimbal_torque, (1, 4))  # some beyond the stall torque
        fp = rng.normal(0.0, 3.0 * lim.max_rotor_torque, (1, 4))
        ref_g, ref_s = servo(0.0, ga, gr, wr, fg, fp)
        d = servo.drive()
        assert drive_torques(d.mode, d.data, 4, ga[0], gr[0], wr[0], fg[0], fp[0], ug, us)
        np.testing.assert_array_equal(ug, ref_g[0])
        np.testing.assert_array_equal(us, ref_s[0])
    # the modes did something: a saturated position loop, an undriven rotor coasting (or not, without a model)
    servo = _servo(params, coast=coast, modes=True)
    g, s = servo(
        0.0, np.zeros((1, 4)), np.zeros((1, 4)), np.full((1, 4), 400.0), np.zeros((1, 4)), np.zeros((1, 4))
    )
    assert g[0, 1] == pytest.approx(servo.gimbal_inertia[1] * lim.max_gimbal_rate / 0.05)
    drag = 0.0 if coast is None else -servo.spin_inertia[3] * 400.0 / coast  # undriven: no motor, drag only
    assert s[0, 3] == drag
    servo.hold(Setpoints(np.zeros((2, 4)), np.zeros((2, 4)), np.zeros(2, bool)))
    with pytest.raises(ConfigError, match="one run"):
        servo.drive()


@pytest.mark.parametrize("coast", [None, 0.8])
def test_the_servos_packed_drive_is_drive_servo_of_its_held_setpoints(coast):
    """``ServoModel.drive()`` (built from Python floats in one array) holds the very data
    :meth:`Drive.servo` builds from the held setpoints: angle targets where a gimbal is on its angle, its
    rate setpoint elsewhere; with and without angle modes and undriven rotors held."""
    params = cubesat_1u()
    rng = np.random.default_rng(11)
    for k in range(40):
        servo = _servo(params, coast=coast, modes=k % 2 == 1)
        if k % 4 == 2:  # rates and speeds alone: every gimbal on its rate, every rotor driven
            servo.hold(
                Setpoints(rng.normal(0.0, 1.0, (1, 4)), rng.uniform(0.0, 600.0, (1, 4)), np.zeros(1, bool))
            )
        target = np.full(4, np.nan) if servo.angle_target is None else servo.angle_target[0]
        undriven = np.zeros(4) if servo.rotor_undriven is None else servo.rotor_undriven[0]
        on_angle = ~np.isnan(target)
        want = Drive.servo(
            servo._header,
            servo.gimbal_inertia,
            servo.spin_inertia,
            np.where(on_angle, target, servo.gimbal_rate_sp[0]),
            on_angle,
            servo.rotor_speed_sp[0],
            undriven,
        )
        got = servo.drive()
        assert got.mode == want.mode
        assert got.data.dtype == want.data.dtype
        np.testing.assert_array_equal(got.data, want.data)


# --------------------------------------------------------------------------- invariants, compiled
def test_momentum_conserved_over_100_s_with_servo_drives_working():
    """Inertial angular momentum, recomputed body by body, stays put over 100 s (10 ms steps: π is advanced
    exactly, so this checks the velocities every step carry it) while the drives turn the gimbals and push
    the rotors, for both presets."""
    for params, duration in ((cubesat_1u(), 100.0), (air_bearing_testbed(), 20.0)):
        plant = Plant(params)
        c = CompiledPlant(plant)
        s = _random_state(plant, 15)
        pi0, e0 = plant.angular_momentum(s)[0], plant.kinetic_energy(s)[0]
        flat = c.pack(s)
        worst = 0.0
        servo = _servo(params, coast=1.0, modes=True)
        for k in range(int(duration)):
            rate = 0.3 * np.sin(0.5 * k + np.arange(plant.n))[None, :]
            servo.hold(Setpoints(rate, np.full((1, plant.n), 450.0 - 50.0 * (k % 3)), np.zeros(1, bool)))
            c.advance(flat, 1e-2, 100, servo)
            pi = plant.angular_momentum(c.unpack(flat))[0]
            worst = max(worst, float(np.linalg.norm(pi - pi0) / np.linalg.norm(pi0)))
        out = c.unpack(flat)
        assert out.t == pytest.approx(s.t + duration)
        assert worst <= 1e-8, params
        assert abs(plant.kinetic_energy(out)[0] - e0) > 1e-3 * e0
        assert so3.orthonormality_error(out.R[0]) < 1e-12


def test_energy_and_momentum_conserved_without_torques_and_at_the_suggested_step():
    plant = Plant(cubesat_1u())
    s = _random_state(plant, 16)
    e0, pi0 = plant.kinetic_energy(s)[0], plant.angular_momentum(s)[0]
    out = CompiledPlant(plant).run(s, 1e-3, 3000)
    assert abs(plant.kinetic_energy(out)[0] - e0) / e0 < 1e-9
    assert np.linalg.norm(plant.angular_momentum(out)[0] - pi0) / np.linalg.norm(pi0) < 1e-12
    assert np.max(np.abs(out.gimbal_angle - s.gimbal_angle)) > 0.1  # free gimbals did move
    # a non-axisymmetric rotor with offset and an asymmetric gimbal, at the step the plant suggests
    unit = UnitParams(
        gimbal_axis=(0, 0, 1),
        spin_axis=(1, 0, 0),
        rotor_inertia=((1.0e-5, 2e-7, 0.0), (2e-7, 5.2e-6, 1e-7), (0.0, 1e-7, 5.9e-6)),
        gimbal_inertia=((1.5e-6, 1e-7, 0), (1e-7, 1.7e-6, 0), (0, 0, 2e-6)),
        rotor_offset_m=2e-3,
    )
    plant = Plant(replace(cubesat_1u(), units=pyramid(4, radius_m=0.025, template=unit)))
    s = _random_state(plant, 17)
    h = plant.suggested_step(s)
    assert h < 3e-4
    e0, pi0 = plant.kinetic_energy(s)[0], plant.angular_momentum(s)[0]
    out = CompiledPlant(plant).run(s, h, int(0.3 / h))
    assert abs(plant.kinetic_energy(out)[0] - e0) / e0 < 1e-8
    assert np.linalg.norm(plant.angular_momentum(out)[0] - pi0) / np.linalg.norm(pi0) < 1e-12


def test_work_of_constant_motor_torques_equals_the_change_of_energy():
    """dT/dt = Σ u_g γ̇ + u_s φ̇, integrated along the compiled run (trapezoid), is the energy change."""
    plant = Plant(cubesat_1u())
    c = CompiledPlant(plant)
    ug, us = np.array([2e-5, -1e-5, 1.5e-5, -2e-5]), np.array([3e-5, -2e-5, 1e-5, 2e-5])
    flat = c.pack(_random_state(plant, 18))
    e0 = plant.kinetic_energy(c.unpack(flat))[0]
    h, work = 1e-3, 0.0
    p_prev = float(ug @ c.gimbal_rate_of(flat) + us @ c.rotor_rate_of(flat))
    for _ in range(1000):
        c.advance(flat, h, 1, (ug, us))
        p = float(ug @ c.gimbal_rate_of(flat) + us @ c.rotor_rate_of(flat))
        work += 0.5 * h * (p + p_prev)
        p_prev = p
    de = plant.kinetic_energy(c.unpack(flat))[0] - e0
    assert abs(de) > 1e-6
    assert de == pytest.approx(work, rel=1e-5)


# --------------------------------------------------------------------------- errors
def test_bad_inputs_raise_as_the_reference_does():
    plant = Plant(cubesat_1u())
    c = CompiledPlant(plant)
    f = c.pack(plant.state())
    with pytest.raises(ConfigError, match="dt"):
        c.step(f, 0.0)
    with pytest.raises(NumericalError, match="non-finite motor torque"):
        c.step(f, 1e-3, ((np.nan, 0, 0, 0), 0.0))
    servo = _servo(cubesat_1u())
    servo.hold(Setpoints(np.full((1, 4), np.nan), np.zeros((1, 4)), np.zeros(1, bool)))
    with pytest.raises(NumericalError, match="non-finite motor torque"):  # NaN passes the limits in both
        plant.step(plant.state(), 1e-3, servo)
    before = f.copy()
    with pytest.raises(NumericalError, match="non-finite motor torque at t = 0 s"):
        c.advance(f, 1e-3, 5, servo)
    np.testing.assert_array_equal(f, before)  # the state is the last good one
    with pytest.raises(NumericalError, match="diverged"):
        c.step(f, 1e-3, (0.0, 1e300))
    with pytest.raises(ConfigError, match="Python torque law"):
        c.step(f, 1e-3, lambda *a: (0.0, 0.0))
    with pytest.raises(ConfigError, match="one run"):
        CompiledPlant(Plant([cubesat_1u(), cubesat_1u()]))
    with pytest.raises(ConfigError, match="batch|one run"):
        c.step_state(Plant(cubesat_1u()).state(batch=2), 1e-3)
    with pytest.raises(ConfigError, match="3 units"):
        c.step(f, 1e-3, ServoModel(air_bearing_testbed()))
    with pytest.raises(ConfigError, match="float64 state"):
        c.advance(f[:-1], 1e-3, 1)
    with pytest.raises(ConfigError, match="path"):
        c.advance(f, 1e-3, 3, None, np.zeros((3, 13)))

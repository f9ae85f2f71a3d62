"""The single-run float plant (hil.vscmg.fast) against the numpy Plant as the reference: the same states to
rounding over thousands of steps (both rotor kinds, both presets, servo / constant / no / arbitrary
torques, gravity gradient), the reference's invariants, and the emulator's World giving the same phone
samples and truth on either plant."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import astuple, fields, replace

import numpy as np
import pytest

from hil import so3
from hil.control.motor_loops import ServoModel, ServoParams, Setpoints
from hil.vscmg import GravityGradient, Plant, PlantState, SpacecraftParams, air_bearing_testbed, cubesat_1u
from hil.vscmg.fast import FastState, SingleRunPlant
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError, NumericalError

FIELDS = tuple(f.name for f in fields(PlantState) if f.name != "t")  # every array of the state
PRESETS: dict[str, Callable[[], SpacecraftParams]] = {
    "cubesat_1u": cubesat_1u,
    "air_bearing_testbed": air_bearing_testbed,
}


def _non_axisymmetric(params):
    """Every rotor with unequal transverse moments and a dynamic imbalance (products of inertia)."""
    units = []
    for u in params.units:
        a, b, c = np.diag(inertia_tensor(u.rotor_inertia, "rotor_inertia"))
        iw = ((a, 0.02 * a, -0.01 * a), (0.02 * a, 0.97 * b, 0.01 * b), (-0.01 * a, 0.01 * b, 1.05 * c))
        units.append(replace(u, rotor_inertia=iw))
    return replace(params, units=tuple(units))


def _coupled_gimbals(params):
    """Every gimbal structure with products of inertia, some coupling the gimbal axis to s and t (the
    terms that turn once per gimbal turn); rotors stay axisymmetric."""
    units = []
    for u in params.units:
        a, b, c = np.diag(inertia_tensor(u.gimbal_inertia, "gimbal_inertia"))
        ig = ((a, 0.05 * a, 0.08 * a), (0.05 * a, b, -0.06 * b), (0.08 * a, -0.06 * b, c))
        units.append(replace(u, gimbal_inertia=ig))
    return replace(params, units=tuple(units))


def _params(preset: str, rotor: str):
    p = PRESETS[preset]()
    if rotor == "coupled-gimbal":
        return _coupled_gimbals(p)
    return p if rotor == "axisymmetric" else _non_axisymmetric(p)


def _start(plant: Plant) -> PlantState:
    rng = np.random.default_rng(11)
    n = plant.n
    return plant.state(
        R=so3.exp(rng.normal(size=3)),
        omega=rng.normal(0.0, 0.05, 3),
        gimbal_angle=rng.uniform(-1.0, 1.0, n),
        gimbal_rate=rng.normal(0.0, 0.3, n),
        rotor_rate=rng.uniform(300.0, 500.0, n),
        rotor_angle=rng.uniform(0.0, 6.0, n),
        t=0.25,
    )


def _servo(params, coast: float | None = None) -> ServoModel:
    """Servos holding non-trivial setpoints: gimbals turning both ways, rotors pushed up and down (an ESC
    that cannot brake with ``coast``)."""
    servo = ServoModel(params, ServoParams(coast_time_constant_s=coast, load_rejection=0.8))
    n = len(params.units)
    gimbal = np.array([[0.4, -0.3, 0.2, -0.1][:n]])
    rotor = np.array([[520.0, 280.0, 450.0, 350.0][:n]])
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
    fast = SingleRunPlant(plant)
    ref = start
    f = fast.from_state(start)
    for _ in range(steps):
        ref = plant.step(ref, h, torques)
        f = fast.step(f, h, torques)
    return fast.to_state(f), ref


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
    start = _start(plant)
    law = _servo(params, coast=0.6) if torques == "servo" else None
    fast, ref = _both(plant, start, 2000, law)
    _assert_same(fast, ref)
    # the motion was not trivial: gimbals and rotors moved, the servos did work (or none did)
    assert np.max(np.abs(fast.gimbal_angle - start.gimbal_angle)) > 0.05
    pi0, e0 = plant.angular_momentum(start)[0], plant.kinetic_energy(start)[0]
    pi, e = plant.angular_momentum(fast)[0], plant.kinetic_energy(fast)[0]
    assert np.linalg.norm(pi - pi0) <= 1e-11 * np.linalg.norm(pi0)  # internal torques never make momentum
    np.testing.assert_allclose(fast.momentum[0], ref.momentum[0], rtol=0, atol=1e-13 * np.linalg.norm(pi0))
    if law is None and rotor != "non-axisymmetric":
        assert abs(e - e0) <= 1e-9 * e0  # free, and 1 ms resolves the axisymmetric plant
    elif law is not None:
        assert abs(e - e0) > 1e-4 * e0  # the motors did change the energy
    assert so3.orthonormality_error(fast.R[0]) < 1e-13


@pytest.mark.parametrize("rotor", ["axisymmetric", "non-axisymmetric", "coupled-gimbal"])
def test_gravity_gradient_with_servos_equals_the_numpy_plant(rotor):
    params = _params("cubesat_1u", rotor)
    # a low orbit whose moment is visible in 2 s: π changes, by R τ
    plant = Plant(params, gravity=GravityGradient(mean_motion=0.05, orbit_normal=(0.0, 0.6, 0.8)))
    start = _start(plant)
    fast, ref = _both(plant, start, 2000, _servo(params))
    _assert_same(fast, ref)
    moved = np.linalg.norm(fast.momentum[0] - start.momentum[0]) / np.linalg.norm(start.momentum[0])
    assert moved > 1e-4  # the gravity gradient did exchange momentum with the orbit


def test_constant_and_arbitrary_torque_laws_equal_the_numpy_plant():
    params = cubesat_1u()
    plant = Plant(params)
    start = _start(plant)
    constant = ([2e-5, -1e-5, 1.5e-5, -2e-5], 3e-5)  # a per-unit gimbal torque, one rotor torque for all
    fast, ref = _both(plant, start, 500, constant)
    _assert_same(fast, ref)

    def law(t, gimbal_angle, gimbal_rate, rotor_rate, gimbal_load, rotor_load):
        ug = 2e-4 * (0.8 * np.sin(0.7 * t + np.arange(4)) - gimbal_rate) - 0.5 * gimbal_load
        us = 2e-4 * np.cos(0.5 * t + gimbal_angle) + 1e-6 * (400.0 - rotor_rate)
        return ug, us

    fast, ref = _both(plant, start, 500, law)
    _assert_same(fast, ref)


def test_per_run_parameters_of_one_run_and_the_plant_state_interface():
    params = _non_axisymmetric(cubesat_1u())
    plant = Plant([params])  # per-run parameters, a batch of one
    assert plant.model.batch == 1
    start = _start(plant)
    fast = SingleRunPlant(plant)
    out = fast.run(start, 1e-3, 50, _servo(params))
    ref = plant.run(start, 1e-3, 50, _servo(params))
    _assert_same(out, ref)
    one = fast.step_state(start, 1e-3)
    _assert_same(one, plant.step(start, 1e-3))
    # conversions are exact both ways
    f = fast.from_state(ref)
    assert isinstance(f, FastState) and f.R == tuple(ref.R[0].ravel())
    back = fast.to_state(f)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(ref, name))
    np.testing.assert_array_equal(f.R_matrix(), ref.R[0])
    np.testing.assert_array_equal(f.omega_array(), ref.omega[0])
    assert list(f.gimbal_angle) == ref.gimbal_angle[0].tolist()
    assert list(f.rotor_momentum) == ref.rotor_momentum[0].tolist()


def test_bad_inputs_raise_as_the_reference_does():
    plant = Plant(cubesat_1u())
    fast = SingleRunPlant(plant)
    f = fast.from_state(plant.state())
    with pytest.raises(ConfigError, match="dt"):
        fast.step(f, 0.0)
    with pytest.raises(NumericalError, match="non-finite motor torque"):
        fast.step(f, 1e-3, ((np.nan, 0, 0, 0), 0.0))
    servo = _servo(cubesat_1u())
    servo.hold(Setpoints(np.full((1, 4), np.nan), np.zeros((1, 4)), np.zeros(1, bool)))
    for step in (fast.step, plant.step):  # a NaN setpoint gets through the servo's limits in both
        with pytest.raises(NumericalError, match="non-finite motor torque"):
            step(f if step == fast.step else plant.state(), 1e-3, servo)
    with pytest.raises(NumericalError, match="diverged"):
        fast.step(f, 1e-3, (0.0, 1e300))
    with pytest.raises(ConfigError, match="one run"):
        SingleRunPlant(Plant([cubesat_1u(), cubesat_1u()]))
    with pytest.raises(ConfigError, match="batch|one run"):
        fast.step_state(Plant(cubesat_1u()).state(batch=2), 1e-3)


# --------------------------------------------------------------------------- the servo's float form
@pytest.mark.parametrize("coast", [None, 0.8])
def test_servo_torques_scalar_is_what_the_servo_computes(coast):
    params = cubesat_1u()
    servo = _servo(params, coast=coast)
    rng = np.random.default_rng(3)
    lim = params.limits
    for _ in range(200):
        gr = rng.normal(0.0, 1.0, (1, 4))
        wr = rng.uniform(200.0, 600.0, (1, 4))
        fg = rng.normal(0.0, 3.0 * lim.max_gimbal_torque, (1, 4))  # some beyond the stall torque
        fp = rng.normal(0.0, 3.0 * lim.max_rotor_torque, (1, 4))
        ug, us = servo(0.0, np.zeros((1, 4)), gr, wr, fg, fp)
        sg, ss = servo.torques_scalar(gr[0].tolist(), wr[0].tolist(), fg[0].tolist(), fp[0].tolist())
        assert sg == ug[0].tolist() and ss == us[0].tolist()
    assert servo.scalar_setpoints() == ([0.4, -0.3, 0.2, -0.1], [520.0, 280.0, 450.0, 350.0])
    servo.hold(Setpoints(np.zeros((2, 4)), np.zeros((2, 4)), np.zeros(2, bool)))
    with pytest.raises(ConfigError, match="one run"):
        servo.scalar_setpoints()


# --------------------------------------------------------------------------- the emulator's world
def _lockstep_world(fast: bool, seconds: float):
    """A World next to its board in lockstep, the board driven through the protocol by a host: rotors spun
    up, gimbals turned both ways. Returns the phone samples, truths and the world."""
    from firmware_sim.transports import EmulatorTransport
    from firmware_sim.world import World
    from hil.link.board import BoardClient
    from hil.scenario import load_scenario
    from hil.timing.clock import LockstepClock
    from protocol.messages import ActuatorSetpoint, UnitSetpoint

    scenario = load_scenario("cubesat-1u")
    clock = LockstepClock()
    link = EmulatorTransport(scenario.emulator_url(), clock)
    client = BoardClient(link, clock=clock)
    client.connect()
    world = World(scenario, link.board, fast=fast)
    client.arm()
    samples, truths = [], []
    period = 0.005
    for k in range(round(seconds / period)):
        clock.advance(period)
        samples += world.advance_to(clock.now())
        t = k * period
        rates = (0.5 * np.sin(2.0 * t), -0.4 * np.cos(1.5 * t), 0.3, -0.2 * np.sin(t))
        speeds = (300.0 + 40 * t, 250.0, 350.0 - 20 * t, 300.0)
        client.send_setpoint(
            ActuatorSetpoint(units=tuple(UnitSetpoint(g, w) for g, w in zip(rates, speeds, strict=True)))
        )
        client.service()
        if k % 20 == 0:
            truths.append(world.truth())
    client.close()
    return samples, truths, world


def test_the_world_gives_the_same_phone_samples_and_truth_on_either_plant():
    fast_samples, fast_truth, world = _lockstep_world(True, 3.0)
    ref_samples, ref_truth, ref_world = _lockstep_world(False, 3.0)
    assert world.fast is not None and ref_world.fast is None
    assert world.steps == ref_world.steps > 2900
    assert len(fast_samples) == len(ref_samples) > 1000
    for a, b in zip(fast_samples, ref_samples, strict=True):
        assert a.kind == b.kind and a.t_s == b.t_s
        np.testing.assert_allclose(a.xyz, b.xyz, rtol=0, atol=1e-9 * max(1.0, float(np.max(np.abs(b.xyz)))))
    for a, b in zip(fast_truth, ref_truth, strict=True):
        assert a.t == b.t
        np.testing.assert_allclose(a.R, b.R, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.omega, b.omega, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.gimbal_angle, b.gimbal_angle, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.gimbal_rate, b.gimbal_rate, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.rotor_speed, b.rotor_speed, rtol=1e-9)
    # the board drove the plant: rotors spun up, gimbals turned, the body moved
    last = fast_truth[-1]
    assert np.min(last.rotor_speed) > 100.0
    assert np.max(np.abs(last.gimbal_angle - fast_truth[0].gimbal_angle)) > 0.1
    assert so3.angle_between(last.R, fast_truth[0].R) > 1e-3
    # the state a host reads under the lock is the plant's state, built from the floats
    s, truth = world.state, world.truth()
    assert s.batch == 1 and s.t == pytest.approx(world.now - world.t0)
    np.testing.assert_array_equal(s.R[0], truth.R)
    np.testing.assert_array_equal(s.omega[0], truth.omega)
    np.testing.assert_allclose(
        [astuple(u) for u in world.unit_states()], [astuple(u) for u in ref_world.unit_states()], atol=1e-9
    )

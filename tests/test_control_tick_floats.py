"""The control tick on Python floats (issue 29, host speed) against the array paths it replaced, kept as
its oracles: steering's one-row kernels called without numba's dispatch against the batched ``momentum``
and ``solve``, the setpoint generator's float path against its numpy batch path, and the whole control
step against the composition of the batched calls — bit for bit, over absurd-but-valid inputs (NaN, ±0,
1e160, rotors stopped or at their limits)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.control.attitude import EigenaxisSlew, Reference
from hil.control.motor_loops import SetpointGenerator
from hil.control.steering import SteeringParams, VscmgSteering
from hil.estimation.estimator import Estimate
from hil.estimation.sensors import StepFlag
from hil.runtime.control_step import ControlStep
from hil.scenario import load_scenario
from hil.so3 import exp
from hil.so3.floats import mat9, vec3
from hil.vscmg import air_bearing_testbed, cubesat_1u

SCENARIO = load_scenario()
N = SCENARIO.spacecraft.n_units

ABSURD = st.sampled_from([math.nan, 0.0, -0.0, 1e160, -1e160, 1e-300, math.pi, 6000.0, -6000.0])
VALUE = st.one_of(st.floats(-1e3, 1e3, allow_nan=False), ABSURD)
SPEED = st.one_of(st.floats(-1200.0, 1200.0, allow_nan=False), ABSURD)
TORQUE = st.one_of(st.floats(-1e-2, 1e-2, allow_nan=False), ABSURD)


def same(a: object, b: object) -> bool:
    """Equal as IEEE bit patterns, element by element (NaN equals NaN, 0.0 is not -0.0)."""
    x = np.asarray(a, dtype=float).reshape(-1)
    y = np.asarray(b, dtype=float).reshape(-1)
    return x.shape == y.shape and x.tobytes() == y.tobytes()


def _steering(null_gain: float, testbed: bool) -> VscmgSteering:
    params = air_bearing_testbed() if testbed else cubesat_1u()
    return VscmgSteering(params, SteeringParams(null_gain=null_gain))


@settings(max_examples=150, deadline=None)
@given(
    st.lists(VALUE, min_size=4, max_size=4),
    st.lists(SPEED, min_size=4, max_size=4),
    st.lists(TORQUE, min_size=3, max_size=3),
    st.sampled_from([0.0, 0.5]),
)
def test_one_row_kernels_give_the_batched_calls_bits(gimbal, rotor, torque, null_gain):
    steer = _steering(null_gain, testbed=False)
    assert same(steer.momentum_one(gimbal, rotor), steer.momentum(gimbal, rotor)[0])
    rates, accels, delta = steer.solve_one(torque, gimbal, rotor, 0.02)
    out = steer.solve(torque, gimbal, rotor, 0.02)
    assert same(rates, out.gimbal_rate[0])
    assert same(accels, out.rotor_accel[0])
    assert same(delta, out.delta[0])
    # an array in gives the same as its floats; a second steering law keeps its own scratch
    other = _steering(null_gain, testbed=True)
    assert same(steer.momentum_one(np.array(gimbal), np.array(rotor)), steer.momentum(gimbal, rotor)[0])
    g3, w3 = gimbal[:3], rotor[:3]
    assert same(other.solve_one(torque, g3, w3, 0.02)[0], other.solve(torque, g3, w3, 0.02).gimbal_rate[0])


def test_one_row_calls_refuse_a_wrong_number_of_values():
    steer = _steering(0.0, testbed=False)
    with pytest.raises(ValueError, match="for 4 units"):
        steer.momentum_one([0.1], [600.0] * 4)  # numpy would broadcast one value to every unit
    with pytest.raises(ValueError, match="for 4 units"):
        steer.solve_one([0.0, 0.0, 0.0], [0.1] * 5, [600.0] * 4, 0.02)
    with pytest.raises(ValueError, match="torque"):
        steer.solve_one([0.0, 0.0], [0.1] * 4, [600.0] * 4, 0.02)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.lists(VALUE, min_size=4, max_size=4),
            st.lists(VALUE, min_size=4, max_size=4),
            st.lists(SPEED, min_size=4, max_size=4),
        ),
        min_size=1,
        max_size=6,
    ),
    st.lists(SPEED, min_size=4, max_size=4),
)
def test_setpoints_on_floats_give_the_numpy_batch_paths_bits(ticks, start):
    """:meth:`SetpointGenerator.update_floats` against :meth:`~SetpointGenerator.update`'s numpy path
    (B = 2: the run and a copy of it, so that the batch path runs), tick after tick."""
    params = cubesat_1u()
    one = SetpointGenerator(params, 50.0, max_lead=20.0)
    batch = SetpointGenerator(params, 50.0, max_lead=20.0)
    one.reset([start])
    batch.reset([start, start])
    steer = VscmgSteering(params)
    for rate, accel, measured in ticks:
        speeds, rates, clamped = one.update_floats(rate, accel, measured)
        cmd = steer.solve(np.zeros((2, 3)), np.zeros((2, 4)), np.full((2, 4), 600.0), 0.02)
        cmd.gimbal_rate[:] = rate
        cmd.rotor_accel[:] = accel
        sp = batch.update(cmd, [measured, measured])
        assert same(speeds, sp.rotor_speed[0])
        assert same(rates, sp.gimbal_rate[0])
        assert clamped == bool(sp.clamped[0])
        assert same(one.rotor_speed, batch.rotor_speed[:1])


def test_setpoints_on_floats_refuse_a_batch():
    gen = SetpointGenerator(cubesat_1u(), 50.0)
    gen.reset(np.full((2, 4), 600.0))
    with pytest.raises(ValueError, match="one run"):
        gen.update_floats([0.0] * 4, [0.0] * 4, [600.0] * 4)


def _estimate(rotation: list[float], omega: list[float]) -> Estimate:
    return Estimate(0.0, exp(np.array(rotation)), omega, (0.0, 0.0, 0.0), StepFlag(0), 0)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),  # the estimate's rotation vector
            st.lists(VALUE, min_size=3, max_size=3),  # its rate
            st.floats(0.0, 30.0),  # the time along the slew
            st.lists(VALUE, min_size=4, max_size=4),  # gimbal angles
            st.lists(SPEED, min_size=4, max_size=4),  # rotor speeds
        ),
        min_size=1,
        max_size=5,
    ),
)
def test_the_control_step_on_floats_gives_the_array_paths_bits(ticks):
    """:meth:`ControlStep.step` (floats end to end) against :meth:`ControlStep.step_arrays` (the batched
    calls it replaced), each on its own control step fed the same ticks: the same setpoint message,
    torque and δ, and the same state left behind (the speed setpoints, the controller's integral)."""
    fast, oracle = ControlStep(SCENARIO), ControlStep(SCENARIO)
    slew = EigenaxisSlew.within_limits(np.eye(3), exp(np.array([0.0, 0.0, 1.5])), 0.1, 0.01)
    for rotation, omega, t, gimbal, rotor in ticks:
        est = _estimate(rotation, omega)
        ref = slew.at(t)
        R9, w3 = est.floats()
        a = fast.step(R9, w3, ref, gimbal, rotor)
        b = oracle.step_arrays(est.R, est.omega, ref, np.array(gimbal), np.array(rotor))
        assert a.setpoint.gimbal_mode is b.setpoint.gimbal_mode
        assert same(
            [(u.gimbal, u.rotor_speed) for u in a.setpoint.units],
            [(u.gimbal, u.rotor_speed) for u in b.setpoint.units],
        )
        assert same(a.torque, b.torque)
        assert same(a.delta, b.delta)
        assert same(fast.setpoints.rotor_speed, oracle.setpoints.rotor_speed)
        assert same(fast.controller.integral, oracle.controller.integral)


@settings(max_examples=100, deadline=None)
@given(st.floats(-5.0, 40.0), st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_a_references_floats_are_its_arrays(t, rotation):
    """What the slew hands the controller as floats (:meth:`Reference.of_floats`) are its arrays' numbers,
    as a reference made from arrays gives them; an estimate's floats are its arrays'."""
    slew = EigenaxisSlew.within_limits(np.eye(3), exp(np.array(rotation)), 0.1, 0.01, start_s=2.0)
    ref = slew.at(t)
    R9, w, wd = ref.floats
    assert (R9, w, wd) == (mat9(ref.R), vec3(ref.omega), vec3(ref.omega_dot))
    assert Reference(ref.R, ref.omega, ref.omega_dot).floats == ref.floats
    est = _estimate(rotation, [math.nan, -0.0, 1e160])
    R9, w3 = est.floats()
    assert same(R9, est.R) and same(w3, est.omega)

"""Steering beside its tested path: required torques and array states that parse but have no finite
command (NaN, infinite, beyond ~1e300 N m, rotor speeds whose D₁ D₁ᵀ overflows). The kernel once
returned NaN gimbal rates flagged as nothing — a command beyond every limit, which the wire then refused
(``ActuatorSetpoint.units[0].gimbal = nan is out of range``) — and its numpy reference raised
LinAlgError."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.control import steering_reference as ref
from hil.control.attitude import Reference
from hil.control.steering import TORQUE_SCALED_ABOVE, Saturation, SteeringParams, VscmgSteering
from hil.runtime.control_step import ControlStep
from hil.scenario import load_scenario
from hil.vscmg import cubesat_1u
from protocol.messages import encode_payload

PARAMS = cubesat_1u()
LIMITS = PARAMS.limits
ABSURD = [math.nan, math.inf, -math.inf, 1e160, -1e308, 1e308, 5e-324, -0.0, 0.0]

absurd_or_plain = st.sampled_from(ABSURD) | st.floats(-1.0, 1.0)


def _bounded_and_flagged(out, b, asked_finite):
    """Row ``b`` of ``out`` is a finite command within every limit; NOT_FINITE alone, with no command,
    exactly where it had none."""
    for name in ("gimbal_rate", "rotor_accel", "torque"):
        assert np.all(np.isfinite(getattr(out, name)[b])), name
    assert np.all(np.abs(out.gimbal_rate[b]) <= LIMITS.max_gimbal_rate * (1 + 1e-12))
    assert np.all(np.abs(out.rotor_accel[b]) <= LIMITS.max_rotor_accel * (1 + 1e-12))
    if out.saturation[b] & Saturation.NOT_FINITE:
        assert out.saturation[b] == Saturation.NOT_FINITE
        assert np.all(out.gimbal_rate[b] == 0.0) and np.all(out.rotor_accel[b] == 0.0)
        assert np.all(out.torque[b] == 0.0) and out.scale[b] == 0.0
    else:
        assert asked_finite, "a non-finite input got a command"


@settings(max_examples=150, deadline=None)
@given(
    torque=st.lists(absurd_or_plain, min_size=3, max_size=3),
    gimbals=st.lists(st.sampled_from([math.nan, math.inf, 0.3]) | st.floats(-7.0, 7.0),
                     min_size=4, max_size=4),
    speeds=st.lists(st.sampled_from([math.nan, math.inf, 1e160, 0.0, 400.0]) | st.floats(0.0, 2500.0),
                    min_size=4, max_size=4),
    null_gain=st.sampled_from([0.0, 0.5]),
)  # fmt: skip
def test_every_input_gets_a_finite_command_within_limits_or_none_flagged(torque, gimbals, speeds, null_gain):
    """The kernel (batched and one-row) and its numpy reference: a finite command within every limit, or
    none at all flagged NOT_FINITE where an input is NaN or infinite; the two agree."""
    steer = VscmgSteering(PARAMS, SteeringParams(null_gain=null_gain))
    finite_in = all(math.isfinite(v) for v in [*torque, *gimbals, *speeds])
    got = steer.solve(torque, gimbals, speeds, 0.02)
    want = ref.solve(steer, torque, gimbals, speeds, 0.02)
    _bounded_and_flagged(got, 0, True)
    _bounded_and_flagged(want, 0, True)
    if not finite_in:
        assert got.saturation[0] == want.saturation[0] == Saturation.NOT_FINITE
    assert (got.saturation[0] & Saturation.NOT_FINITE) == (want.saturation[0] & Saturation.NOT_FINITE)
    np.testing.assert_allclose(got.gimbal_rate, want.gimbal_rate, rtol=1e-6, atol=1e-9)
    rates, accels, _ = steer.solve_one(torque, gimbals, speeds, 0.02)
    assert rates == got.gimbal_rate[0].tolist() and accels == got.rotor_accel[0].tolist()


@settings(max_examples=60, deadline=None)
@given(
    direction=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(lambda v: math.hypot(*v) > 1e-3),
    size_exp=st.integers(100, 308) | st.integers(304, 308),  # overflowed from ~1e305 N m on
    gimbals=st.lists(st.floats(-3.0, 3.0), min_size=4, max_size=4),
)
def test_a_huge_torque_is_steered_as_its_direction_at_the_threshold(direction, size_exp, gimbals):
    """A required torque of 1e100…1e308 N m: the command the threshold-sized torque of its direction
    gets (saturated to the limits), never NaN — 1e308 N m once gave NaN gimbal rates, flagged nothing."""
    steer = VscmgSteering(PARAMS)
    u = np.array(direction) / max(abs(v) for v in direction)
    rotor = np.full(4, 400.0)
    got = steer.solve(u * 10.0**size_exp * 0.999, gimbals, rotor, 0.02)
    at = steer.solve(u * TORQUE_SCALED_ABOVE, gimbals, rotor, 0.02)
    assert not got.saturation[0] & Saturation.NOT_FINITE
    assert got.saturation[0] & (Saturation.GIMBAL_RATE | Saturation.ROTOR_ACCEL)
    np.testing.assert_allclose(got.gimbal_rate, at.gimbal_rate, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.rotor_accel, at.rotor_accel, rtol=1e-9, atol=1e-12)
    want = ref.solve(steer, u * 10.0**size_exp * 0.999, gimbals, rotor, 0.02)
    np.testing.assert_allclose(got.gimbal_rate, want.gimbal_rate, rtol=1e-7, atol=1e-9)


def test_the_control_step_on_a_non_finite_estimate_sends_what_the_wire_takes():
    """The default scenario's control step with an estimate whose rate is NaN (or infinite): a setpoint
    the wire encodes — gimbals still, rotors held — instead of one it refuses."""
    scenario = load_scenario("cubesat-1u")
    step = ControlStep(scenario)
    n = scenario.spacecraft.n_units
    rotor = [scenario.spacecraft.nominal_rotor_speed] * n
    step.reset(np.array(rotor))
    reference = Reference(np.eye(3))
    identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    for rate in ((math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (1e160, 1e160, 1e160)):
        steered = step.step(identity, rate, reference, [0.1] * n, rotor)
        encode_payload(steered.setpoint)  # FieldRangeError before
        assert all(u.gimbal == 0.0 for u in steered.setpoint.units)
        assert all(u.rotor_speed == rotor[0] for u in steered.setpoint.units)

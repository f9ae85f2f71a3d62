"""Controller gains beside their tested path: values each valid on its own (positive, finite) whose
matrices at the spacecraft's inertia are not — ω_n² J overflowing to inf (every torque NaN: inf · 0 at
zero error) or underflowing to 0 (no attitude feedback) — and weights or an integral time that are
infinite. They were taken; the control step then steered with NaN, or nothing, for a controller."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.control.attitude import AttitudeController, ControllerGains, Reference
from hil.control.motor_loops import SetpointGenerator
from hil.control.steering import VscmgSteering
from hil.runtime.control_step import ControlStep
from hil.scenario import load_scenario
from hil.so3 import exp
from hil.so3.floats import mat9
from hil.vscmg import cubesat_1u
from protocol.errors import ConfigError

SCENARIO = load_scenario("cubesat-1u")
N = SCENARIO.spacecraft.n_units

positive = st.sampled_from(
    [1e-300, 1e-170, 1e-100, 1e-3, 0.7, 1e100, 1e150, 1e160, 1e300, math.inf]
) | st.floats(1e-3, 100.0)


def _gains(**fields) -> ControllerGains | None:
    try:
        return ControllerGains(**fields)
    except ConfigError:
        return None


@settings(max_examples=200, deadline=None)
@given(
    natural_frequency=positive,
    damping=positive,
    weight=positive,
    integral_time_s=st.none() | positive,
    integral_limit=positive,
)
def test_gains_are_refused_or_give_finite_torques(
    natural_frequency, damping, weight, integral_time_s, integral_limit
):
    """Gains through the control step of the default scenario: a ConfigError naming the gains at
    construction, or a finite torque on every tick of a plain slew error, from zero error on."""
    gains = _gains(
        natural_frequency=natural_frequency,
        damping=damping,
        weights=(1.0, weight, 1.0),
        integral_time_s=integral_time_s,
        integral_limit=integral_limit,
    )
    if gains is None:
        return
    scenario = replace(SCENARIO, loop=replace(SCENARIO.loop, gains=gains))
    try:
        step = ControlStep(scenario)
    except ConfigError as exc:
        assert "gains" in str(exc)
        return
    rotor = [SCENARIO.spacecraft.nominal_rotor_speed] * N
    step.reset(np.array(rotor))
    for angle in (0.0, 1e-3, 0.5, 3.0):
        attitude = mat9(exp(np.array([angle, -0.5 * angle, 0.2 * angle])))
        steered = step.step(attitude, (0.01, 0.0, -0.02), Reference(np.eye(3)), [0.1] * N, rotor)
        assert all(math.isfinite(v) for v in steered.torque), (gains, angle, steered.torque)


@pytest.mark.parametrize(
    "fields",
    [
        {"natural_frequency": 1e160},  # ω_n² overflows: K_R = inf
        {"natural_frequency": 1e-170},  # ω_n² J underflows: K_R = 0, no attitude feedback
        {"weights": (math.inf, 1.0, 1.0)},
        {"integral_time_s": math.inf},
        {"integral_time_s": 5e-324},  # K_R ∫e_R / T_i overflows
    ],
)
def test_each_absurd_gain_is_refused_naming_it(fields):
    with pytest.raises(ConfigError, match="gains|weights|integral_time_s"):
        ControlStep(replace(SCENARIO, loop=replace(SCENARIO.loop, gains=ControllerGains(**fields))))


@pytest.mark.parametrize("frame_rate_hz", [math.nan, 0.0, -50.0, -math.inf])
def test_a_frame_rate_that_is_not_a_rate_is_refused(frame_rate_hz):
    """NaN passed the control-rate-within-frame-rate check (every comparison with NaN is false)."""
    with pytest.raises(ConfigError, match="frame_rate_hz|faster"):
        SetpointGenerator(SCENARIO.spacecraft, 50.0, frame_rate_hz)


def test_one_non_finite_tick_does_not_poison_the_integral_term():
    """With an integral term, one tick on a NaN attitude estimate made ∫e_R NaN for good: every later
    torque NaN (and, since steering gives no command for a NaN torque, the array never steered again).
    The tick is lost; the ticks after it are those of a controller that never saw it."""
    gains = ControllerGains(0.7, 0.9, integral_time_s=20.0)
    inertia = np.diag([2.1e-3, 2.3e-3, 2.5e-3])
    seen, unseen = AttitudeController(inertia, gains), AttitudeController(inertia, gains)
    reference = Reference(np.eye(3))
    R = exp(np.array([0.3, -0.2, 0.1]))
    for controller in (seen, unseen):
        controller.update(R, [0.01, 0.0, 0.0], reference, 0.02)
    for bad in (np.full((3, 3), math.nan), np.where(np.eye(3) > 0, math.inf, 0.0)):  # a NaN attitude estimate
        out = seen.update(bad, [0.01, 0.0, 0.0], reference, 0.02)
        assert not np.all(np.isfinite(out.torque))
    for _ in range(3):
        a = seen.update(R, [0.01, 0.0, 0.0], reference, 0.02)
        b = unseen.update(R, [0.01, 0.0, 0.0], reference, 0.02)
        np.testing.assert_array_equal(a.torque, b.torque)
    assert np.all(np.isfinite(seen.integral))


@pytest.mark.parametrize("speed", [0.0, 1e-60])
def test_a_vehicle_whose_rotors_do_not_spin_is_refused_by_steering_naming_the_speed(speed):
    """h̄ = 0 (a nominal rotor speed of 0, which the limits allowed) was a ZeroDivisionError in the run's
    warm-up; a tiny one underflowed h̄⁶ to the same."""
    base = cubesat_1u()
    params = replace(base, limits=replace(base.limits, min_rotor_speed=0.0), nominal_rotor_speed=speed)
    with pytest.raises(ConfigError) as caught:
        VscmgSteering(params)
    assert caught.value.where == "SpacecraftParams.nominal_rotor_speed"

"""The VSCMG plant just beside its tested numerics: steps far longer than any it is built for, and
spacecraft whose every figure is finite and physical but whose model overflows or underflows float64.

Found by the fourth hunt:

- a step of 1e6 s left the integrated momenta finite but the attitude NaN; both the numpy plant and the
  compiled one returned that state (NaN body rate, NaN rotor speeds) as a good one;
- a rotor of 1e160 kg m² overflowed its gimbal/rotor block's determinant: D⁻¹ became 0 and the numpy plant
  stepped a rotor spinning at 400 rad/s to 0 rad/s without a word (the compiled plant called it diverged);
  a pivot 1e200 m out gave NaN states from ``PlantModel.state``; a bus of 1e110 kg m² was stepped by the
  numpy plant and refused by the compiled one.

Each is now a NumericalError (the step) or a ConfigError naming the field when the plant is built, the
same from the numpy reference, the compiled plant and the host's :class:`PlantModel`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.world.models.compiled import CompiledPlant
from firmware_sim.world.models.plant import Plant
from hil.vscmg import PlantModel, air_bearing_testbed, cubesat_1u
from protocol.errors import ConfigError, NumericalError

PRESETS = {"cubesat_1u": cubesat_1u(), "air_bearing_testbed": air_bearing_testbed()}
PLANTS = {name: Plant(p) for name, p in PRESETS.items()}
COMPILED = {name: CompiledPlant(p) for name, p in PLANTS.items()}

rates = st.floats(-2.0, 2.0, allow_nan=False)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    preset=st.sampled_from(sorted(PRESETS)),
    omega=st.tuples(rates, rates, rates),
    gimbal_rate=rates,
    dt=st.floats(1.0, 1e9),  # within the far time (test_dynamics_beside_hunt4_far_times.py)
)
def test_a_step_far_too_long_is_refused_or_finite_never_a_nan_state(preset, omega, gimbal_rate, dt):
    """Whatever a step of dt seconds makes of a turning spacecraft, the state it returns is finite in every
    field, or the step raises NumericalError and leaves the compiled state as it was."""
    plant, compiled = PLANTS[preset], COMPILED[preset]
    s = plant.state(omega=omega, gimbal_rate=gimbal_rate)
    with np.errstate(all="ignore"):
        try:
            s1 = plant.step(s, dt)
        except NumericalError:
            pass
        else:
            for field in ("R", "momentum", "omega", "gimbal_rate", "rotor_rate", "rotor_momentum"):
                assert np.all(np.isfinite(getattr(s1, field))), (field, getattr(s1, field))
        flat = compiled.pack(s)
        before = flat.copy()
        try:
            compiled.advance(flat, dt, 1)
        except NumericalError:
            np.testing.assert_array_equal(flat, before)
        else:
            assert np.all(np.isfinite(flat)), flat


def test_a_step_of_a_million_seconds_is_called_diverged_by_both_plants():
    plant = PLANTS["cubesat_1u"]
    s = plant.state(omega=(0.5, 0.2, 0.1))
    with np.errstate(all="ignore"):
        with pytest.raises(NumericalError, match="diverged at t = 1e\\+06 s"):
            plant.step(s, 1e6)
        with pytest.raises(NumericalError, match="diverged at t = 1e\\+06 s"):
            COMPILED["cubesat_1u"].step(COMPILED["cubesat_1u"].pack(s), 1e6)


def _every_unit(params, **changes):
    return replace(params, units=tuple(replace(u, **changes) for u in params.units))


def _models(params):
    """Each way the plant is built from parameters: the host's model, the numpy plant, the compiled one."""
    yield lambda: PlantModel(params)
    yield lambda: Plant(params)
    yield lambda: CompiledPlant(Plant(params))
    yield lambda: Plant([params, params])


@settings(max_examples=25, deadline=None)
@given(preset=st.sampled_from(sorted(PRESETS)), exponent=st.floats(155.0, 300.0))
def test_a_rotor_too_heavy_to_compute_with_is_refused_naming_it(preset, exponent):
    big = 10.0**exponent
    params = _every_unit(PRESETS[preset], rotor_inertia=(big, 0.6 * big, 0.6 * big))
    for build in _models(params):
        with pytest.raises(ConfigError, match=r"units\[0\]\.rotor_inertia"):
            build()


@settings(max_examples=25, deadline=None)
@given(preset=st.sampled_from(sorted(PRESETS)), exponent=st.floats(162.0, 323.0))
def test_a_gimbal_and_rotor_too_light_to_compute_with_are_refused_naming_them(preset, exponent):
    tiny = 10.0**-exponent
    params = _every_unit(
        PRESETS[preset], rotor_inertia=(tiny, 0.6 * tiny, 0.6 * tiny), gimbal_inertia=(tiny, tiny, tiny)
    )
    for build in _models(params):
        with pytest.raises(ConfigError, match=r"units\[0\]\.rotor_inertia, gimbal_inertia"):
            build()


@settings(max_examples=25, deadline=None)
@given(
    preset=st.sampled_from(sorted(PRESETS)),
    exponent=st.floats(155.0, 300.0),
    field=st.sampled_from(["position_m", "rotor_offset_m", "gimbal_offset_m"]),
)
def test_a_part_too_far_out_to_compute_with_is_refused_naming_it(preset, exponent, field):
    far = 10.0**exponent
    value = (far, 0.0, 0.0) if field == "position_m" else far
    params = _every_unit(PRESETS[preset], **{field: value})
    for build in _models(params):
        with pytest.raises(ConfigError, match=r"units\[0\]\.\w+_mass_kg, position_m, \w+_offset_m"):
            build()


@settings(max_examples=25, deadline=None)
@given(preset=st.sampled_from(sorted(PRESETS)), exponent=st.floats(105.0, 300.0))
def test_a_bus_too_heavy_to_compute_with_is_refused_by_every_plant_alike(preset, exponent):
    big = 10.0**exponent
    params = replace(PRESETS[preset], bus_inertia=(big, big, big))
    for build in _models(params):
        with pytest.raises(ConfigError, match=r"SpacecraftParams\.bus_inertia"):
            build()


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_figures_beside_the_limits_still_build_and_both_plants_agree(preset):
    """A heavy but computable rotor and bus (1e100 kg m² the rotor, 1e60 the bus) and a light one are still
    plants, and the compiled step equals the numpy one on them."""
    heavy = replace(_every_unit(PRESETS[preset], rotor_inertia=(1e100, 6e99, 6e99)), bus_inertia=(1e60,) * 3)
    light = _every_unit(PRESETS[preset], rotor_inertia=(1e-80, 6e-81, 6e-81))
    for params in (heavy, light):
        plant = Plant(params)
        compiled = CompiledPlant(plant)
        s = plant.state(omega=(0.01, -0.02, 0.005), gimbal_rate=0.1)
        reference = plant.run(s, 1e-3, 20)
        stepped = compiled.run(s, 1e-3, 20)
        for field in ("omega", "gimbal_rate", "rotor_rate", "momentum"):
            np.testing.assert_allclose(
                getattr(stepped, field), getattr(reference, field), rtol=1e-9, atol=1e-12, err_msg=field
            )
        np.testing.assert_allclose(reference.momentum, s.momentum, rtol=1e-9)  # torque-free: π conserved

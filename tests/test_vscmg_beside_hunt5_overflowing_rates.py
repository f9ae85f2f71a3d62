"""The VSCMG plant's states just beside their tested speeds: body rates, gimbal rates and rotor speeds each
finite but so large that the state's momenta or kinetic energy overflow float64.

Found by the fifth hunt: ``PlantModel.state(omega=(1e160, 0, 0))`` (or a rotor speed or gimbal rate of
1e160 rad/s) returned a state of infinite kinetic energy, and one of 1e300 rad/s infinite momenta, as a
good state, on the host's model and the world's plant alike. Now such a state is a ConfigError naming the
velocity; every state that is built has finite momenta and energy.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from firmware_sim.world.models.plant import Plant
from hil.vscmg import PlantModel, air_bearing_testbed, cubesat_1u
from protocol.errors import ConfigError

MODELS = {
    "host cubesat_1u": PlantModel(cubesat_1u()),
    "world air_bearing_testbed": Plant(air_bearing_testbed()),
}
VELOCITIES = ("omega", "gimbal_rate", "rotor_rate")


def _velocity(model: PlantModel, field: str, value: float) -> dict:
    size = 3 if field == "omega" else model.n
    return {field: np.full(size, value)}


@settings(max_examples=120, deadline=None)
@given(
    st.sampled_from(sorted(MODELS)),
    st.sampled_from(VELOCITIES),
    st.floats(1e100, 1.7e308, allow_nan=False, allow_infinity=False),
    st.sampled_from([1.0, -1.0]),
)
@example("host cubesat_1u", "omega", 1e160, 1.0)
@example("host cubesat_1u", "rotor_rate", 1e160, 1.0)
@example("world air_bearing_testbed", "gimbal_rate", 1e160, -1.0)
@example("host cubesat_1u", "omega", 1e300, 1.0)
def test_a_state_too_fast_is_refused_naming_its_velocity_or_is_finite(name, field, size, sign):
    model = MODELS[name]
    try:
        state = model.state(**_velocity(model, field, sign * size))
    except ConfigError as e:
        assert e.where == f"PlantState.{field}"
        assert "overflow" in e.detail
        return
    for what, value in (
        ("momentum", state.momentum),
        ("gimbal_momentum", state.gimbal_momentum),
        ("rotor_momentum", state.rotor_momentum),
        ("angular_momentum", model.angular_momentum(state)),
        ("kinetic_energy", model.kinetic_energy(state)),
    ):
        assert np.all(np.isfinite(value)), f"{name}: {field} = {sign * size:g} rad/s gave {what} {value}"


@pytest.mark.parametrize("name", sorted(MODELS))
def test_ordinary_and_signed_zero_rates_still_build_the_same_state(name):
    model = MODELS[name]
    plain = model.state(omega=(0.01, -0.02, 0.03), gimbal_rate=0.1, rotor_rate=300.0)
    assert np.all(np.isfinite(model.kinetic_energy(plain)))
    zero = model.state(omega=(-0.0, -0.0, -0.0), gimbal_rate=-0.0, rotor_rate=-0.0)
    assert model.kinetic_energy(zero)[0] == 0.0

"""Vehicle parameters given through the Python API as something other than numbers — a string, None, a
list where one number is due, ragged rows, another object where limits are due. Each field used to raise
numpy's or Python's own ValueError or TypeError ("could not convert string to float: 'abc'", "'<=' not
supported between instances of 'float' and 'str'") naming no field; a pyramid of 4.5 units a bare
TypeError from numpy. Now each is a ConfigError naming the field, as bad numbers already were.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.vscmg import ActuatorLimits, SpacecraftParams, cubesat_1u, pyramid
from protocol.errors import ConfigError

not_numbers = st.sampled_from(["abc", None, object(), [1.0, [2.0]], {"a": 1}, "", b"\x00"])
not_one_number = not_numbers | st.sampled_from([[1.0, 2.0], (0.5,), [[1.0]]])

UNIT = cubesat_1u().units[0]
SPACECRAFT = cubesat_1u()

UNIT_FIELDS = [
    "gimbal_axis",
    "spin_axis",
    "position_m",
    "gimbal_inertia",
    "rotor_inertia",
    "gimbal_mass_kg",
    "rotor_mass_kg",
    "gimbal_offset_m",
    "rotor_offset_m",
]
LIMIT_FIELDS = [
    "max_gimbal_rate",
    "min_rotor_speed",
    "max_rotor_speed",
    "max_gimbal_torque",
    "max_rotor_torque",
    "max_rotor_accel",
]
SPACECRAFT_FIELDS = ["bus_inertia", "bus_mass_kg", "bus_com_m", "nominal_rotor_speed", "limits"]


@settings(max_examples=60, deadline=None)
@given(field=st.sampled_from(UNIT_FIELDS), value=not_numbers)
def test_a_unit_field_that_is_not_numbers_is_a_config_error_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"UnitParams\.{field}"):
        replace(UNIT, **{field: value})


@settings(max_examples=60, deadline=None)
@given(field=st.sampled_from(LIMIT_FIELDS), value=not_one_number)
def test_an_actuator_limit_that_is_not_one_number_is_a_config_error_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"ActuatorLimits\.{field}"):
        replace(SPACECRAFT.limits, **{field: value})


@settings(max_examples=60, deadline=None)
@given(field=st.sampled_from(SPACECRAFT_FIELDS), value=not_one_number)
def test_a_spacecraft_field_that_is_not_numbers_is_a_config_error_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"SpacecraftParams\.{field}"):
        replace(SPACECRAFT, **{field: value})


@pytest.mark.parametrize("n", [4.5, "4", None, True])
def test_a_pyramid_of_no_whole_number_of_units_is_a_config_error(n):
    with pytest.raises(ConfigError, match=r"pyramid\.n"):
        pyramid(n)


def test_numbers_in_any_numeric_type_are_still_taken():

    unit = replace(UNIT, rotor_mass_kg=np.float32(0.02), rotor_offset_m=np.int64(0), position_m=[0, 0, 0])
    assert isinstance(SpacecraftParams(SPACECRAFT.bus_inertia, (unit,)), SpacecraftParams)
    assert len(pyramid(np.int64(5))) == 5
    assert ActuatorLimits(max_gimbal_rate=2).max_gimbal_rate == 2

"""The spacecraft with its array of variable-speed control moment gyroscopes: parameters, geometries, the
model (mass matrix, momenta, energy) and the plant's state with what the model says of it
(:mod:`.plant_model`: the locked inertia the controller starts from, the invariants). Pure math, no I/O;
docs/dynamics.md derives the equations. Stepping the plant in time, the motor drives and the simulated phone
are the world's: :mod:`firmware_sim.world.models`."""

from .geometry import (
    PYRAMID_BETA,
    TETRAHEDRON_BETA,
    air_bearing_testbed,
    cubesat_1u,
    custom_array,
    pyramid,
    spin_axes_at,
    tetrahedron,
)
from .params import RPM, ActuatorLimits, SpacecraftParams, UnitParams
from .plant_model import PlantModel, PlantState

__all__ = [
    "PYRAMID_BETA",
    "RPM",
    "TETRAHEDRON_BETA",
    "ActuatorLimits",
    "PlantModel",
    "PlantState",
    "SpacecraftParams",
    "UnitParams",
    "air_bearing_testbed",
    "cubesat_1u",
    "custom_array",
    "pyramid",
    "spin_axes_at",
    "tetrahedron",
]

"""The spacecraft with its array of variable-speed control moment gyroscopes: parameters, geometries, the
model (mass matrix, momenta, energy) and the plant integrator. Pure math, no I/O; docs/dynamics.md derives
the equations."""

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
from .plant import GravityGradient, Plant, PlantState, TorqueLaw, Torques

__all__ = [
    "PYRAMID_BETA",
    "RPM",
    "TETRAHEDRON_BETA",
    "ActuatorLimits",
    "GravityGradient",
    "Plant",
    "PlantState",
    "SpacecraftParams",
    "TorqueLaw",
    "Torques",
    "UnitParams",
    "air_bearing_testbed",
    "cubesat_1u",
    "custom_array",
    "pyramid",
    "spin_axes_at",
    "tetrahedron",
]

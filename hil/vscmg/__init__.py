"""The spacecraft with its array of variable-speed control moment gyroscopes: parameters, geometries, the
model (mass matrix, momenta, energy) and the plant integrator (numpy, batched: the reference; and
:mod:`.compiled`, the same step for one run compiled, with the motor drives of :mod:`.drives`). Pure math,
no I/O; docs/dynamics.md derives the equations."""

from .compiled import CompiledPlant
from .drives import Drive
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
    "CompiledPlant",
    "Drive",
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

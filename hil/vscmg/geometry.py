"""Array geometries and parameter presets: a skewed pyramid of n units (4 with β = 54.74° is the classic
near-spherical momentum envelope), the 3-unit tetrahedron of the paper's air-bearing testbed, any custom set
of gimbal and spin axes, and two complete spacecraft (:func:`cubesat_1u`, :func:`air_bearing_testbed`).

Pyramid convention: unit i sits at azimuth θᵢ = 2π i/n about the body z axis; its gimbal axis is the
normal of a pyramid face tilted β from z, ``gᵢ = (sin β cos θᵢ, sin β sin θᵢ, cos β)``, and its spin axis at
γ = 0 is horizontal, ``sᵢ = (−sin θᵢ, cos θᵢ, 0)``, so the rotors' momenta cancel at zero gimbal angles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from protocol.errors import ConfigError

from .params import RPM, ActuatorLimits, SpacecraftParams, UnitParams, _floats, _number

PYRAMID_BETA = math.acos(1.0 / math.sqrt(3.0))
"""54.74°: the skew angle that makes the 4-unit pyramid's momentum envelope nearly spherical."""
TETRAHEDRON_BETA = math.acos(1.0 / 3.0)
"""70.53°: the lateral faces of a regular tetrahedron standing on its base."""


def custom_array(
    gimbal_axes: ArrayLike,
    spin_axes: ArrayLike,
    positions_m: ArrayLike | None = None,
    template: UnitParams | None = None,
) -> tuple[UnitParams, ...]:
    """Units with the given gimbal axes (n, 3) and spin axes at γ = 0 (n, 3), body frame; positions (n, 3) m
    (default: all at the reference point). Inertias and masses come from ``template`` (default
    :class:`UnitParams`' defaults). Axes must be unit vectors, each spin axis perpendicular to its gimbal
    axis (ConfigError naming the unit otherwise)."""
    g = np.asarray(gimbal_axes, dtype=float)
    s = np.asarray(spin_axes, dtype=float)
    if g.ndim != 2 or g.shape[1] != 3 or s.shape != g.shape:
        raise ConfigError(f"need matching (n, 3) axes, got {g.shape} and {s.shape}", "custom_array")
    p = np.zeros_like(g) if positions_m is None else np.asarray(positions_m, dtype=float)
    if p.shape != g.shape:
        raise ConfigError(f"need (n, 3) positions, got {p.shape}", "custom_array.positions_m")
    base = template or UnitParams(gimbal_axis=(0.0, 0.0, 1.0), spin_axis=(1.0, 0.0, 0.0))
    units = []
    for i in range(len(g)):
        try:
            units.append(
                replace(base, gimbal_axis=tuple(g[i]), spin_axis=tuple(s[i]), position_m=tuple(p[i]))
            )
        except ConfigError as e:
            raise ConfigError(e.detail, f"unit {i}: {e.where}") from e
    return tuple(units)


def pyramid(
    n: int = 4,
    beta: float = PYRAMID_BETA,
    radius_m: float = 0.0,
    height_m: float = 0.0,
    template: UnitParams | None = None,
) -> tuple[UnitParams, ...]:
    """n units on the faces of a pyramid with skew angle ``beta`` (rad), pivots on a circle of ``radius_m``
    at height ``height_m`` (see the module docstring for the axes). Each argument that is no finite number
    raises ConfigError naming it (``beta="x"`` raised a bare TypeError, ``radius_m="x"`` numpy's)."""
    if not isinstance(n, int | np.integer) or isinstance(n, bool) or n < 3:
        raise ConfigError(f"a pyramid needs a whole number of units, at least 3, got {n!r}", "pyramid.n")
    beta = _number(beta, "pyramid.beta")
    radius_m, height_m = _number(radius_m, "pyramid.radius_m"), _number(height_m, "pyramid.height_m")
    if not 0.0 <= beta <= math.pi / 2:
        raise ConfigError(f"must lie in [0, 90] degrees, got {math.degrees(beta):.3g}", "pyramid.beta")
    theta = 2.0 * math.pi * np.arange(n) / n
    c, s = np.cos(theta), np.sin(theta)
    g = np.stack([math.sin(beta) * c, math.sin(beta) * s, np.full(n, math.cos(beta))], axis=1)
    spin = np.stack([-s, c, np.zeros(n)], axis=1)
    pos = np.stack([radius_m * c, radius_m * s, np.full(n, height_m)], axis=1)
    return custom_array(g, spin, pos, template)


def tetrahedron(
    radius_m: float = 0.0, height_m: float = 0.0, template: UnitParams | None = None
) -> tuple[UnitParams, ...]:
    """Three units on the lateral faces of a regular tetrahedron (the paper's testbed array)."""
    return pyramid(3, TETRAHEDRON_BETA, radius_m, height_m, template)


def cubesat_1u(beta: float = PYRAMID_BETA, rotor_offset_m: float = 0.5e-3) -> SpacecraftParams:
    """A 1U CubeSat (≈1.3 kg, J ≈ 2.3·10⁻³ kg m²) with a 4-unit pyramid of small VSCMGs: rotors of
    1·10⁻⁵ kg m² (20 g, ~32 mm) spun at 400 rad/s nominal, 6000 rpm at most; gimbal rates ≤ 1.5 rad/s.
    The rotor centres of mass sit ``rotor_offset_m`` (σ) along their gimbal axes (a mounting tolerance)."""
    unit = UnitParams(
        gimbal_axis=(0.0, 0.0, 1.0),
        spin_axis=(1.0, 0.0, 0.0),
        gimbal_inertia=(1.5e-6, 1.5e-6, 2.0e-6),
        gimbal_mass_kg=0.010,
        rotor_inertia=(1.0e-5, 5.5e-6, 5.5e-6),
        rotor_mass_kg=0.020,
        rotor_offset_m=rotor_offset_m,
    )
    return SpacecraftParams(
        bus_inertia=((2.00e-3, 2.0e-5, 0.0), (2.0e-5, 2.10e-3, 1.0e-5), (0.0, 1.0e-5, 2.20e-3)),
        units=pyramid(4, beta, radius_m=0.025, height_m=-0.02, template=unit),
        bus_mass_kg=1.2,
        limits=ActuatorLimits(
            max_gimbal_rate=1.5,
            min_rotor_speed=150.0,
            max_rotor_speed=6000.0 * RPM,
            max_gimbal_torque=2.0e-2,
            max_rotor_torque=1.0e-2,
            max_rotor_accel=200.0,
        ),
        nominal_rotor_speed=400.0,
    )


def air_bearing_testbed(rotor_offset_m: float = 2.0e-3) -> SpacecraftParams:
    """A tabletop air-bearing spacecraft simulator with the paper's 3-unit tetrahedron (representative
    figures for such a testbed, ~10 kg and J ≈ 0.07–0.1 kg m²; the paper's own values are not used)."""
    unit = UnitParams(
        gimbal_axis=(0.0, 0.0, 1.0),
        spin_axis=(1.0, 0.0, 0.0),
        gimbal_inertia=(4.0e-5, 4.0e-5, 5.0e-5),
        gimbal_mass_kg=0.15,
        rotor_inertia=(1.5e-4, 8.0e-5, 8.0e-5),
        rotor_mass_kg=0.25,
        rotor_offset_m=rotor_offset_m,
    )
    return SpacecraftParams(
        bus_inertia=(0.065, 0.070, 0.095),
        units=tetrahedron(radius_m=0.12, height_m=0.05, template=unit),
        bus_mass_kg=8.0,
        limits=ActuatorLimits(
            max_gimbal_rate=2.0,
            min_rotor_speed=100.0,
            max_rotor_speed=1000.0,
            max_gimbal_torque=0.2,
            max_rotor_torque=0.05,
            max_rotor_accel=100.0,
        ),
        nominal_rotor_speed=500.0,
    )


def spin_axes_at(units: Sequence[UnitParams], gimbal_angles: ArrayLike) -> np.ndarray:
    """Spin axes (n, 3), body frame, of ``units`` at ``gimbal_angles`` (n,) rad. Angles that are not n
    finite numbers raise ConfigError naming the first bad unit: NaN or inf gave axes of NaN, a wrong count
    numpy's bare broadcast error."""
    gam = _floats(gimbal_angles, "spin_axes_at.gimbal_angles")
    if gam.shape != (len(units),):
        raise ConfigError(
            f"need one angle for each of the {len(units)} units, got shape {gam.shape}",
            "spin_axes_at.gimbal_angles",
        )
    bad = np.flatnonzero(~np.isfinite(gam))
    if bad.size:
        i = int(bad[0])
        raise ConfigError(
            f"must be a finite angle (rad), got {float(gam[i])!r}", f"spin_axes_at.gimbal_angles[{i}]"
        )
    g = np.array([u.gimbal_axis for u in units])
    s0 = np.array([u.spin_axis for u in units])
    t0 = np.cross(g, s0)
    return np.cos(gam)[:, None] * s0 + np.sin(gam)[:, None] * t0

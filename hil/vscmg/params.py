"""Parameters of a spacecraft carrying an array of VSCMGs: the bus, each unit's gimbal structure and rotor,
and the actuator limits. Frozen dataclasses, validated on construction (a bad value raises
:class:`~protocol.errors.ConfigError` naming the field).

Frames (docs/dynamics.md, "Frames"):

- body: the bus frame; ``R`` maps body vectors to the inertial frame.
- gimbal frame of unit i, columns ``(s, t, g)``: ``g`` the gimbal axis (fixed in the body), ``s`` the rotor's
  spin axis, ``t = g × s``. At gimbal angle γ, ``s(γ) = cos γ s₀ + sin γ t₀``.
- rotor frame of unit i, columns ``(s, w₂, w₃)``: the gimbal frame turned by the rotor angle φ about ``s``.

Inertia tensors are 3×3 (kg m²), each about its body's own centre of mass and expressed in that body's frame:
the gimbal structure's in ``(s, t, g)``, the rotor's in ``(s, w₂, w₃)``. Off-diagonal entries are allowed
(a non-axisymmetric rotor, an asymmetric gimbal). The rotor's centre of mass sits ``rotor_offset_m`` (σ)
along the gimbal axis from the gimbal pivot; the gimbal structure's ``gimbal_offset_m`` likewise. Both are
therefore fixed in the body, so the system's centre of mass does not move as gimbals and rotors turn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.errors import ConfigError

Array = NDArray[np.float64]

RPM = 2.0 * math.pi / 60.0  # rad/s per rpm


def inertia_tensor(value: ArrayLike, where: str) -> Array:
    """A validated inertia tensor (3, 3) from a 3-vector (principal moments) or a 3×3 matrix.

    Checks: finite, symmetric (to 1e-12 relative), positive definite and physically realisable (the
    principal moments satisfy the triangle inequality ``I₁ + I₂ ≥ I₃``)."""
    a = _floats(value, where)
    if a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ConfigError(f"must be 3 principal moments or a finite 3x3 matrix, got {value!r}", where)
    scale = float(np.max(np.abs(a)))
    if scale == 0.0 or np.max(np.abs(a - a.T)) > 1e-12 * scale:
        raise ConfigError("must be a non-zero symmetric matrix", where)
    moments = np.linalg.eigvalsh(a)
    if moments[0] <= 0.0:
        raise ConfigError(f"must be positive definite (principal moments {moments})", where)
    if moments[0] + moments[1] < moments[2] * (1.0 - 1e-9):
        raise ConfigError(f"principal moments {moments} violate the triangle inequality", where)
    return a


def unit_vector(value: ArrayLike, where: str) -> Array:
    """A finite 3-vector of unit length (to 1e-6); raises ConfigError otherwise."""
    v = _floats(value, where)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"must be a finite 3-vector, got {value!r}", where)
    n = float(np.linalg.norm(v))
    if abs(n - 1.0) > 1e-6:
        raise ConfigError(f"must have unit length, has {n:.9g}", where)
    return v / n


def _floats(value: ArrayLike, where: str) -> Array:
    """``value`` as a float64 array; ConfigError naming ``where`` for what is not numbers (a string, None,
    ragged lists), where numpy's own ValueError or TypeError named no field."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"must be numbers, got {value!r}", where) from e


def _number(value: float, where: str) -> float:
    """``value`` as one finite float; ConfigError naming ``where`` otherwise."""
    x = _floats(value, where)
    if x.shape != () or not math.isfinite(float(x)):
        raise ConfigError(f"must be a finite number, got {value!r}", where)
    return float(x)


def _positive(value: float, where: str, allow_zero: bool = False) -> float:
    a = _floats(value, where)
    x = float(a) if a.shape == () else math.nan  # several numbers where one is due: refused below
    if not math.isfinite(x) or x < 0.0 or (x == 0.0 and not allow_zero):
        raise ConfigError(
            f"must be {'non-negative' if allow_zero else 'positive'} and finite, got {value!r}", where
        )
    return x


@dataclass(frozen=True)
class UnitParams:
    """One VSCMG: geometry, gimbal structure and rotor.

    ``gimbal_axis`` (3,) and ``spin_axis`` (3,) unit vectors in the body frame (the spin axis at γ = 0,
    perpendicular to the gimbal axis); ``position_m`` (3,) the gimbal pivot in the body frame relative to
    the bus reference point (m). ``gimbal_inertia`` and ``rotor_inertia``: principal moments (3,) or 3×3
    tensors in the gimbal frame ``(s, t, g)`` and rotor frame ``(s, w₂, w₃)`` (kg m²); ``rotor_offset_m`` σ
    and ``gimbal_offset_m`` the centres of mass along the gimbal axis from the pivot (m).
    """

    gimbal_axis: tuple[float, float, float]
    spin_axis: tuple[float, float, float]
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gimbal_inertia: tuple = (1.5e-6, 1.5e-6, 2.0e-6)
    gimbal_mass_kg: float = 0.010
    gimbal_offset_m: float = 0.0
    rotor_inertia: tuple = (1.0e-5, 5.5e-6, 5.5e-6)
    rotor_mass_kg: float = 0.020
    rotor_offset_m: float = 0.0

    def __post_init__(self) -> None:
        g = unit_vector(self.gimbal_axis, "UnitParams.gimbal_axis")
        s = unit_vector(self.spin_axis, "UnitParams.spin_axis")
        if abs(float(g @ s)) > 1e-6:
            raise ConfigError(
                f"must be perpendicular to the gimbal axis (g·s = {g @ s:.3g})", "UnitParams.spin_axis"
            )
        p = _floats(self.position_m, "UnitParams.position_m")
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ConfigError(f"must be a finite 3-vector, got {self.position_m!r}", "UnitParams.position_m")
        inertia_tensor(self.gimbal_inertia, "UnitParams.gimbal_inertia")
        inertia_tensor(self.rotor_inertia, "UnitParams.rotor_inertia")
        _positive(self.gimbal_mass_kg, "UnitParams.gimbal_mass_kg", allow_zero=True)
        _positive(self.rotor_mass_kg, "UnitParams.rotor_mass_kg", allow_zero=True)
        for name in ("gimbal_offset_m", "rotor_offset_m"):
            _number(getattr(self, name), f"UnitParams.{name}")

    @property
    def rotor_spin_inertia(self) -> float:
        """The rotor's moment about its spin axis, ``s·I_W·s`` (kg m²)."""
        return float(inertia_tensor(self.rotor_inertia, "UnitParams.rotor_inertia")[0, 0])

    @property
    def axisymmetric_rotor(self) -> bool:
        """True when the rotor's inertia is invariant under its own spin (no fast terms at 2φ̇)."""
        i = inertia_tensor(self.rotor_inertia, "UnitParams.rotor_inertia")
        off_diagonal = i - np.diag(np.diag(i))
        return bool(abs(i[1, 1] - i[2, 2]) <= 1e-12 * i[0, 0] and not off_diagonal.any())


@dataclass(frozen=True)
class ActuatorLimits:
    """What the motors can do. Rotor speeds are relative to the gimbal, one-directional (ESCs that do not
    reverse): ``min_rotor_speed`` keeps the rotor spinning so the unit always has CMG authority.

    ``max_gimbal_rate`` rad/s, ``min/max_rotor_speed`` rad/s, ``max_gimbal_torque`` and ``max_rotor_torque``
    N m (the motors' stall torques, used by the servo models), ``max_rotor_accel`` rad/s² (what steering may
    ask of a rotor)."""

    max_gimbal_rate: float = 1.5
    min_rotor_speed: float = 150.0
    max_rotor_speed: float = 6000.0 * RPM
    max_gimbal_torque: float = 5.0e-3
    max_rotor_torque: float = 5.0e-3
    max_rotor_accel: float = 200.0

    def __post_init__(self) -> None:
        for name in (
            "max_gimbal_rate",
            "max_rotor_speed",
            "max_gimbal_torque",
            "max_rotor_torque",
            "max_rotor_accel",
        ):
            _positive(getattr(self, name), f"ActuatorLimits.{name}")
        _positive(self.min_rotor_speed, "ActuatorLimits.min_rotor_speed", allow_zero=True)
        if self.min_rotor_speed >= self.max_rotor_speed:
            raise ConfigError("must be below max_rotor_speed", "ActuatorLimits.min_rotor_speed")


MIN_BUS_MOMENT_KG_M2 = 1e-6
"""The smallest principal moment a bus may have (kg m²): a 1U CubeSat's are ~2e-3, an air-bearing table's
~1. A bus of 5e-324 kg m² passed as positive definite, and its run failed safe 52 times and ended 163 deg
off, "completed"."""


@dataclass(frozen=True)
class SpacecraftParams:
    """The bus and its VSCMG array.

    ``bus_inertia`` principal moments (3,) or a 3×3 tensor about the bus's own centre of mass, body frame
    (kg m²); ``bus_mass_kg``; ``bus_com_m`` (3,) the bus's centre of mass relative to the bus reference
    point (m); ``units`` the VSCMGs; ``limits`` their actuator limits; ``nominal_rotor_speed`` rad/s the
    speed the rotors are spun up to and that steering's h̄ refers to.
    """

    bus_inertia: tuple
    units: tuple[UnitParams, ...]
    bus_mass_kg: float = 1.0
    bus_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    limits: ActuatorLimits = field(default_factory=ActuatorLimits)
    nominal_rotor_speed: float = 400.0

    def __post_init__(self) -> None:
        bus = inertia_tensor(self.bus_inertia, "SpacecraftParams.bus_inertia")
        smallest = float(np.linalg.eigvalsh(bus)[0])
        if smallest < MIN_BUS_MOMENT_KG_M2:
            raise ConfigError(
                f"its smallest principal moment {smallest:.3g} kg m² is below {MIN_BUS_MOMENT_KG_M2:g} "
                "(a 10 g, 1 cm part): no spacecraft",
                "SpacecraftParams.bus_inertia",
            )
        _positive(self.bus_mass_kg, "SpacecraftParams.bus_mass_kg")
        c = _floats(self.bus_com_m, "SpacecraftParams.bus_com_m")
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigError(
                f"must be a finite 3-vector, got {self.bus_com_m!r}", "SpacecraftParams.bus_com_m"
            )
        if not self.units:
            raise ConfigError("needs at least one unit", "SpacecraftParams.units")
        for i, u in enumerate(self.units):
            if not isinstance(u, UnitParams):
                raise ConfigError(
                    f"must be UnitParams, got {type(u).__name__}", f"SpacecraftParams.units[{i}]"
                )
        if not isinstance(self.limits, ActuatorLimits):
            raise ConfigError(
                f"must be ActuatorLimits, got {type(self.limits).__name__}", "SpacecraftParams.limits"
            )
        lo, hi = self.limits.min_rotor_speed, self.limits.max_rotor_speed
        if not lo <= _number(self.nominal_rotor_speed, "SpacecraftParams.nominal_rotor_speed") <= hi:
            raise ConfigError(
                f"must lie within the rotor speed limits [{lo}, {hi}] rad/s",
                "SpacecraftParams.nominal_rotor_speed",
            )

    @property
    def n_units(self) -> int:
        return len(self.units)

    @property
    def total_mass_kg(self) -> float:
        return self.bus_mass_kg + sum(u.gimbal_mass_kg + u.rotor_mass_kg for u in self.units)

    def point_masses(self) -> tuple[Array, Array]:
        """Masses (k,) and centre-of-mass positions (k, 3) of every body (bus, then per unit gimbal and
        rotor), relative to the bus reference point (m). All are fixed in the body frame."""
        masses = [self.bus_mass_kg]
        positions = [np.asarray(self.bus_com_m, dtype=float)]
        for u in self.units:
            g = np.asarray(u.gimbal_axis, dtype=float)
            p = np.asarray(u.position_m, dtype=float)
            masses += [u.gimbal_mass_kg, u.rotor_mass_kg]
            positions += [p + u.gimbal_offset_m * g, p + u.rotor_offset_m * g]
        return np.array(masses), np.array(positions)

    @property
    def center_of_mass_m(self) -> Array:
        """The system's centre of mass (3,), body frame, relative to the bus reference point (m)."""
        m, p = self.point_masses()
        return (m @ p) / m.sum()

    @property
    def nominal_wheel_momentum(self) -> float:
        """h̄: one rotor's spin momentum at the nominal speed (N m s)."""
        return float(np.mean([u.rotor_spin_inertia for u in self.units])) * self.nominal_rotor_speed

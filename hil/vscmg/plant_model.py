"""The VSCMG spacecraft's state and what the model says of it: :class:`PlantState` (attitude, momenta,
angles and the velocities they imply) and :class:`PlantModel`, which builds states from velocities and
reads their invariants — angular momentum, kinetic energy, the array's momentum, the locked inertia
J(γ, φ) — from the equations of :mod:`.model`.

This is the part of the plant the host needs (the controller's inertia at the starting configuration);
integrating the equations in time is the world's job (:class:`firmware_sim.world.models.plant.Plant`, a
:class:`PlantModel` with the RKMK4 step). Batch: every array carries a leading batch axis B (runs in
parallel, e.g. a Monte Carlo campaign); a single run is B = 1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from protocol.errors import ConfigError

from . import model as mdl
from .params import SpacecraftParams

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlantState:
    """The plant at time ``t`` (s), batch B. Integrated variables: ``R`` (B, 3, 3) body → inertial,
    ``momentum`` (B, 3) the inertial angular momentum π (N m s), ``gimbal_angle`` γ and ``rotor_angle`` φ
    (B, n) rad (φ relative to the gimbal, kept in [0, 2π)), ``gimbal_momentum`` p_γ and ``rotor_momentum``
    p_φ (B, n) N m s. Derived from them: ``omega`` Ω (B, 3) body rate, ``gimbal_rate`` γ̇ and ``rotor_rate``
    φ̇ (B, n) rad/s (rotor speed relative to its gimbal, what an ESC controls)."""

    t: float
    R: Array
    momentum: Array
    gimbal_angle: Array
    rotor_angle: Array
    gimbal_momentum: Array
    rotor_momentum: Array
    omega: Array
    gimbal_rate: Array
    rotor_rate: Array

    @property
    def batch(self) -> int:
        return int(self.R.shape[0])


class PlantModel:
    """The spacecraft with its VSCMG array as equations: build states, select runs of a batch, and read
    their invariants (the plant that steps them in time is :class:`firmware_sim.world.models.plant.Plant`).

    ``params``: one spacecraft shared by every run of a batch, or a sequence of B spacecraft, one per run
    (each run's true parameters, e.g. a Monte Carlo batch with dispersed inertia, misaligned gimbal axes or
    rotor offsets; states must then have batch B). Per-run spacecraft must share their unit count, actuator
    limits and nominal rotor speed (what states and steps read from ``self.params``)."""

    def __init__(self, params: SpacecraftParams | Sequence[SpacecraftParams]) -> None:
        if isinstance(params, SpacecraftParams):
            self.params = params
            self.model = mdl.ArrayModel.build(params)
        else:
            runs = tuple(params)
            self.model = mdl.ArrayModel.build_batch(runs)
            self.params = runs[0]
            for i, p in enumerate(runs):
                if (p.limits, p.nominal_rotor_speed) != (self.params.limits, self.params.nominal_rotor_speed):
                    raise ConfigError(
                        "per-run spacecraft must share actuator limits and nominal rotor speed",
                        f"Plant.params[{i}]",
                    )
        self.n = self.model.n

    # ------------------------------------------------------------------ states
    def state(
        self,
        R: ArrayLike | None = None,
        omega: ArrayLike = (0.0, 0.0, 0.0),
        gimbal_angle: ArrayLike = 0.0,
        gimbal_rate: ArrayLike = 0.0,
        rotor_rate: ArrayLike | None = None,
        rotor_angle: ArrayLike = 0.0,
        t: float = 0.0,
        batch: int | None = None,
    ) -> PlantState:
        """A state from velocities. Arguments broadcast to (B, 3, 3), (B, 3) and (B, n); unbatched values
        give B = 1 (or ``batch``; or the plant's B with per-run parameters). ``rotor_rate`` defaults to the
        nominal rotor speed."""
        given = ((R, 3), (omega, 2), (gimbal_angle, 2), (gimbal_rate, 2), (rotor_rate, 2), (rotor_angle, 2))
        b = max([batch or 1] + [np.shape(v)[0] for v, full in given if v is not None and np.ndim(v) == full])
        if self.model.batch is not None:
            if b not in (1, self.model.batch):
                raise ConfigError(
                    f"the plant has parameters for {self.model.batch} runs, not {b}", "PlantState"
                )
            b = self.model.batch
        n = self.n
        R = np.broadcast_to(np.eye(3) if R is None else np.asarray(R, float), (b, 3, 3)).copy()
        if not all(so3.is_rotation(r, 1e-6) for r in R):
            raise ConfigError("must be rotation matrices", "PlantState.R")
        rr = self.params.nominal_rotor_speed if rotor_rate is None else rotor_rate
        omega_ = _finite(np.broadcast_to(np.asarray(omega, float), (b, 3)), "omega")
        ga = _finite(np.broadcast_to(np.asarray(gimbal_angle, float), (b, n)), "gimbal_angle")
        gr = _finite(np.broadcast_to(np.asarray(gimbal_rate, float), (b, n)), "gimbal_rate")
        ra = _finite(np.broadcast_to(np.asarray(rotor_angle, float), (b, n)), "rotor_angle")
        wr = _finite(np.broadcast_to(np.asarray(rr, float), (b, n)), "rotor_rate")
        R = np.stack([so3.project(r) for r in R])
        cfg = mdl.configuration(self.model, ga, ra)
        with np.errstate(over="ignore", invalid="ignore"):  # refused below, naming the velocity
            rates = mdl.body_rates(self.model, cfg, omega_, gr, wr)
            H, pg, pp = mdl.momenta(self.model, cfg, omega_, rates)
            momentum = np.einsum("bij,bj->bi", R, H)
            energy = mdl.kinetic_energy(self.model, omega_, rates)
        if not all(np.all(np.isfinite(a)) for a in (momentum, pg, pp, energy)):
            self._refuse_overflowing_velocities(cfg, omega_, gr, wr)
        return PlantState(
            float(t),
            R,
            momentum,
            ga.copy(),
            np.mod(ra, 2 * np.pi),
            pg,
            pp,
            omega_.copy(),
            gr.copy(),
            wr.copy(),
        )

    def _refuse_overflowing_velocities(
        self, cfg: mdl.Configuration, omega: Array, gimbal_rate: Array, rotor_rate: Array
    ) -> None:
        """Raise ConfigError naming the velocity (rad/s) whose momenta or kinetic energy overflow float64.

        Each was checked finite alone, but a body rate or rotor speed of 1e160 rad/s gave a state of
        infinite energy (and 1e300, infinite momenta), returned as a good one for the plant to step."""
        zeros_b3, zeros_bn = np.zeros_like(omega), np.zeros_like(gimbal_rate)
        alone = {
            "omega": (omega, zeros_bn, zeros_bn),
            "gimbal_rate": (zeros_b3, gimbal_rate, zeros_bn),
            "rotor_rate": (zeros_b3, zeros_bn, rotor_rate),
        }
        named = []
        with np.errstate(over="ignore", invalid="ignore"):
            for name, (w, gr, wr) in alone.items():
                rates = mdl.body_rates(self.model, cfg, w, gr, wr)
                energy = mdl.kinetic_energy(self.model, w, rates)
                if not all(np.all(np.isfinite(a)) for a in (*mdl.momenta(self.model, cfg, w, rates), energy)):
                    named.append(name)
        fields = ", ".join(f"PlantState.{name}" for name in named or alone)
        raise ConfigError(
            "too fast to compute with: the momenta or kinetic energy of this state overflow float64 "
            f"(largest |rate| {max(float(np.max(np.abs(a))) for a in (omega, gimbal_rate, rotor_rate)):.3g} "
            "rad/s)",
            fields,
        )

    def select(self, state: PlantState, index: int | slice) -> PlantState:
        """The runs ``index`` of a batch (an int keeps a batch axis of 1)."""
        idx = slice(index, index + 1) if isinstance(index, int) else index
        return PlantState(state.t, *(getattr(state, f)[idx] for f in _ARRAY_FIELDS))

    # ------------------------------------------------------------------ invariants and outputs
    def _rates(self, s: PlantState) -> tuple[mdl.Configuration, mdl.BodyRates]:
        cfg = mdl.configuration(self.model, s.gimbal_angle, s.rotor_angle)
        return cfg, mdl.body_rates(self.model, cfg, s.omega, s.gimbal_rate, s.rotor_rate)

    def angular_momentum(self, s: PlantState) -> Array:
        """Inertial angular momentum ``R (J₀Ω + Σ C (h_G + h_W))`` (B, 3) N m s, recomputed body by body from
        the velocities (independently of the integrated π)."""
        cfg, rates = self._rates(s)
        H, _, _ = mdl.momenta(self.model, cfg, s.omega, rates)
        return np.einsum("bij,bj->bi", s.R, H)

    def kinetic_energy(self, s: PlantState) -> Array:
        """Rotational kinetic energy (B,) J."""
        _, rates = self._rates(s)
        return mdl.kinetic_energy(self.model, s.omega, rates)

    def array_momentum(self, s: PlantState) -> Array:
        """Momentum the array carries relative to a locked body, body frame (B, 3) N m s."""
        cfg = mdl.configuration(self.model, s.gimbal_angle, s.rotor_angle)
        return mdl.array_momentum(cfg, s.gimbal_rate, s.rotor_rate)

    def locked_inertia(self, s: PlantState) -> Array:
        """J(γ, φ) (B, 3, 3) kg m², about the system's centre of mass, body frame."""
        return mdl.configuration(self.model, s.gimbal_angle, s.rotor_angle).J


_ARRAY_FIELDS = (
    "R",
    "momentum",
    "gimbal_angle",
    "rotor_angle",
    "gimbal_momentum",
    "rotor_momentum",
    "omega",
    "gimbal_rate",
    "rotor_rate",
)


def _finite(a: Array, name: str) -> Array:
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"must be finite, got {a!r}", f"PlantState.{name}")
    return a

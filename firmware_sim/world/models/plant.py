"""The VSCMG spacecraft plant: inputs and a Lie-group integrator (docs/dynamics.md, "Integration"), on the
states of :class:`hil.vscmg.PlantModel` (which builds them and reads their invariants: the host needs those,
the stepping in time is the world's).

The integrator carries momenta, not velocities: the inertial angular momentum ``π = R Π`` (3,), the gimbal
and rotor momenta ``p_γ, p_φ`` (n,) and the angles, with ``R`` on SO(3)::

    Ṙ = R Ω^×     π̇ = R τ_ext     (Ω, γ̇, φ̇) = M⁻¹ (Rᵀπ, p_γ, p_φ)     ṗ_γ = u_g + ∂T/∂γ     ṗ_φ = u_s + ∂T/∂φ

stepped by the fourth-order Runge–Kutta–Munthe-Kaas method (RKMK4): ``R`` is advanced as ``R₀ exp(Θ)``
with ``Θ`` from RK4 on ``Θ̇ = dexp⁻¹_Θ(Ω)`` (truncated after the second commutator, enough for order
four), so it stays a rotation to rounding (one Newton–Schulz polar correction per step removes the
rounding). With no external torque π̇ = 0 and π is conserved to rounding at any step size — internal
motor torques move momentum between body, gimbals and rotors but never create it. Energy, attitude and
rates are accurate to O(h⁴).

Step size: the gimbal–body coupling (nutation at ``h_rotor / √(J_gimbal J_body)``, ~50–100 rad/s at 1U
scale) wants h ≤ 1 ms; a non-axisymmetric rotor adds terms at twice the spin rate (~1200 rad/s at 6000
rpm), which want h ≤ 0.1 ms. :meth:`Plant.suggested_step` says which.

Batch: every array carries a leading batch axis B (runs in parallel, e.g. a Monte Carlo campaign); a
single run is B = 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.vscmg import PlantModel, PlantState, SpacecraftParams
from hil.vscmg import model as mdl
from protocol.errors import ConfigError, NumericalError

from .kernels import MAX_TIME_S

Array = NDArray[np.float64]

TorqueLaw = Callable[[float, Array, Array, Array, Array, Array], tuple[Array, Array]]
"""``law(t, gimbal_angle, gimbal_rate, rotor_rate, gimbal_load, rotor_load) ->
(gimbal_torque, rotor_torque)``,
all (B, n): motor drivers evaluated at every integrator stage (continuous-time servos). The loads (N m) are
the gyroscopic generalised forces ∂T/∂γ and ∂T/∂φ acting on each gimbal and rotor, what a servo's
disturbance rejection works against."""

Torques = TorqueLaw | tuple[ArrayLike, ArrayLike] | None
"""Motor torques (N m) for one step: a :data:`TorqueLaw`, a ``(gimbal, rotor)`` pair held over the step
(arrays broadcastable to (B, n)), or None for none."""


@dataclass(frozen=True)
class GravityGradient:
    """Gravity-gradient moment on a circular orbit of mean motion ``mean_motion`` (rad/s):
    ``τ = 3 n² r̂ × J r̂`` with ``r̂`` the body-frame unit vector from the Earth's centre and J the locked
    inertia J(γ, φ) about the centre of mass. The orbit's radial direction turns in the inertial frame from
    ``radial_at_epoch`` (t = 0) about ``orbit_normal`` (both inertial unit vectors)."""

    mean_motion: float
    orbit_normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    radial_at_epoch: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mean_motion) and self.mean_motion >= 0.0):
            raise ConfigError(
                f"must be a non-negative rate, got {self.mean_motion!r}", "GravityGradient.mean_motion"
            )
        n, r = np.asarray(self.orbit_normal, float), np.asarray(self.radial_at_epoch, float)
        if abs(np.linalg.norm(n) - 1) > 1e-6 or abs(np.linalg.norm(r) - 1) > 1e-6 or abs(n @ r) > 1e-6:
            raise ConfigError(
                "orbit_normal and radial_at_epoch must be perpendicular unit vectors", "GravityGradient"
            )

    @classmethod
    def circular(cls, altitude_m: float, **kw: tuple[float, float, float]) -> GravityGradient:
        """The orbit at ``altitude_m`` above a spherical Earth (μ = 3.986004418e14 m³/s², R = 6378.137 km)."""
        a = 6378.137e3 + altitude_m
        return cls(math.sqrt(3.986004418e14 / a**3), **kw)

    def radial(self, t: float) -> Array:
        """Inertial unit vector (3,) from the Earth's centre to the spacecraft at time ``t`` (s)."""
        r0 = np.asarray(self.radial_at_epoch, float)
        a = self.mean_motion * t
        return math.cos(a) * r0 + math.sin(a) * np.cross(self.orbit_normal, r0)

    def torque(self, t: float, R: Array, J: Array) -> Array:
        """Body-frame moment (B, 3) N m for attitudes ``R`` (B, 3, 3) and locked inertias ``J`` (B, 3, 3)."""
        rb = np.einsum("bji,j->bi", R, self.radial(t))
        return 3.0 * self.mean_motion**2 * _cross(rb, np.einsum("bij,bj->bi", J, rb))


class Plant(PlantModel):
    """The spacecraft with its VSCMG array, stepped in time: a :class:`PlantModel` (states, invariants)
    with the RKMK4 step.

    ``params``: as :class:`PlantModel` (one spacecraft, or one per run of a batch). ``gravity``: an
    optional :class:`GravityGradient` (the only external moment modelled)."""

    def __init__(
        self, params: SpacecraftParams | Sequence[SpacecraftParams], gravity: GravityGradient | None = None
    ) -> None:
        super().__init__(params)
        self.gravity = gravity

    def suggested_step(self, s: PlantState | None = None) -> float:
        """A step (s) that resolves the fastest dynamics: 1 ms, or 0.25/(2 |φ̇|max) with non-axisymmetric
        rotors (≤ 0.2 ms at 6000 rpm)."""
        if self.model.axisymmetric:
            return 1e-3
        wmax = self.params.limits.max_rotor_speed if s is None else float(np.max(np.abs(s.rotor_rate)))
        return min(1e-3, 0.25 / max(2.0 * wmax, 1e-9))

    # ------------------------------------------------------------------ integration
    def step(self, s: PlantState, dt: float, torques: Torques = None) -> PlantState:
        """Advance ``s`` by ``dt`` seconds (RKMK4) under ``torques``; raises NumericalError if the state
        stops being finite (a diverging run) or the inputs are not finite."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ConfigError(f"must be a positive step, got {dt!r}", "Plant.step.dt")
        check_time_reached(s.t, dt, 1, "Plant.step")
        if self.model.batch not in (None, s.batch):
            raise ConfigError(
                f"the plant has parameters for {self.model.batch} runs, not {s.batch}", "Plant.step"
            )
        n, t0, h = self.n, s.t, dt
        x0 = np.concatenate(
            [s.momentum, s.gimbal_angle, s.rotor_angle, s.gimbal_momentum, s.rotor_momentum], 1
        )
        R0 = s.R
        w1, f1 = self._derivative(t0, R0, x0, torques, (s.omega, s.gimbal_rate, s.rotor_rate))
        th2 = 0.5 * h * w1
        w2, f2 = self._derivative(t0 + 0.5 * h, R0 @ _exp(th2), x0 + 0.5 * h * f1, torques)
        d2 = _dexpinv(th2, w2)
        th3 = 0.5 * h * d2
        w3, f3 = self._derivative(t0 + 0.5 * h, R0 @ _exp(th3), x0 + 0.5 * h * f2, torques)
        d3 = _dexpinv(th3, w3)
        th4 = h * d3
        w4, f4 = self._derivative(t0 + h, R0 @ _exp(th4), x0 + h * f3, torques)
        d4 = _dexpinv(th4, w4)
        R = _reorthonormalize(R0 @ _exp(h / 6.0 * (w1 + 2.0 * d2 + 2.0 * d3 + d4)))
        x = x0 + h / 6.0 * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        _check_diverged(t0 + h, h, x, R)
        pi, ga, ra = x[:, :3], x[:, 3 : 3 + n], np.mod(x[:, 3 + n : 3 + 2 * n], 2.0 * np.pi)
        pg, pp = x[:, 3 + 2 * n : 3 + 3 * n], x[:, 3 + 3 * n :]
        cfg = mdl.configuration(self.model, ga, ra)
        omega, gr, wr = mdl.velocities(self.model, cfg, np.einsum("bji,bj->bi", R, pi), pg, pp)
        _check_diverged(t0 + h, h, omega, gr, wr)
        return PlantState(t0 + h, R, pi, ga, ra, pg, pp, omega, gr, wr)

    def run(
        self,
        s: PlantState,
        dt: float,
        n_steps: int,
        torques: Torques = None,
        observe: Callable[[PlantState], None] | None = None,
    ) -> PlantState:
        """``n_steps`` steps of ``dt``; ``observe(state)`` after each (e.g. to record)."""
        for _ in range(n_steps):
            s = self.step(s, dt, torques)
            if observe is not None:
                observe(s)
        return s

    def _derivative(
        self,
        t: float,
        R: Array,
        x: Array,
        torques: Torques,
        known: tuple[Array, Array, Array] | None = None,
    ) -> tuple[Array, Array]:
        """``(Ω, ẋ)`` at one stage; ``known`` velocities skip the mass-matrix solve (the first stage)."""
        n, m = self.n, self.model
        pi, ga, ra = x[:, :3], x[:, 3 : 3 + n], x[:, 3 + n : 3 + 2 * n]
        cfg = mdl.configuration(m, ga, ra)
        if known is None:
            H = np.einsum("bji,bj->bi", R, pi)
            omega, gr, wr = mdl.velocities(m, cfg, H, x[:, 3 + 2 * n : 3 + 3 * n], x[:, 3 + 3 * n :])
        else:
            omega, gr, wr = known
        fg, fp = mdl.internal_forces(mdl.body_rates(m, cfg, omega, gr, wr), wr)
        if torques is not None:
            ug, us = torques(t, ga, gr, wr, fg, fp) if callable(torques) else torques
            ug, us = np.asarray(ug, float), np.asarray(us, float)
            if not (np.all(np.isfinite(ug)) and np.all(np.isfinite(us))):
                raise NumericalError(f"non-finite motor torque at t = {t:.6g} s: gimbal {ug}, rotor {us}")
            fg = fg + ug
            fp = fp + us
        if self.gravity is not None:
            dpi = np.einsum("bij,bj->bi", R, self.gravity.torque(t, R, cfg.J))
        else:
            dpi = np.zeros_like(pi)
        return omega, np.concatenate([dpi, gr, wr, fg, fp], axis=1)


def check_time_reached(t: float, dt: float, steps: int, where: str) -> None:
    """Refuse ``steps`` steps of ``dt`` s from time ``t`` (s) that would leave ±:data:`.kernels.MAX_TIME_S`
    (or start from a time that is not finite): there a step's length is lost to float64 rounding, up to
    the whole step (ConfigError naming ``where``)."""
    end = t + dt * steps
    if not (abs(t) <= MAX_TIME_S and abs(end) <= MAX_TIME_S):
        raise ConfigError(
            f"steps from t = {t!r} s to {end!r} s, beyond ±{MAX_TIME_S:.6g} s where float64 keeps 1 µs",
            f"{where}.t",
        )


def _check_diverged(t: float, h: float, *arrays: Array) -> None:
    """Raise NumericalError unless every array of the new state is finite. The attitude and the velocities
    are checked as well as the integrated momenta and angles: a step far too long (1e6 s) left the momenta
    finite but the attitude, and so every velocity read from it, NaN, and returned that state as good."""
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise NumericalError(f"the plant state diverged at t = {t:.6g} s (step {h:g} s too long?)")


def _cross(a: Array, b: Array) -> Array:
    """``a × b`` for (B, 3) arrays (np.cross's axis handling costs more than the arithmetic at this size)."""
    a0, a1, a2 = a[:, 0:1], a[:, 1:2], a[:, 2:3]
    b0, b1, b2 = b[:, 0:1], b[:, 1:2], b[:, 2:3]
    return np.concatenate([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _exp(phi: Array) -> Array:
    """Rodrigues, ``exp(φ^×) = I + a φ^× + b (φ^×)²``, a = sin θ/θ, b = (1 − cos θ)/θ², for (B, 3) →
    (B, 3, 3); series below θ = 1e-4 rad (integrator increments are small)."""
    th2 = np.einsum("bi,bi->b", phi, phi)
    if np.all(th2 < 1e-8):
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = np.sqrt(th2)
        safe = np.where(th2 < 1e-8, 1.0, th)
        a = np.where(th2 < 1e-8, 1.0 - th2 / 6.0, np.sin(safe) / safe)
        b = np.where(th2 < 1e-8, 0.5 - th2 / 24.0, 2.0 * (np.sin(0.5 * safe) / safe) ** 2)
    k = np.zeros(phi.shape + (3,))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    return _EYE + a[:, None, None] * k + b[:, None, None] * (k @ k)


_EYE = np.eye(3)


def _dexpinv(theta: Array, w: Array) -> Array:
    """``dexp⁻¹_Θ(w) ≈ w − ½ Θ×w + (1/12) Θ×(Θ×w)`` (B, 3): exact to O(|Θ|³), enough for RKMK4."""
    c = _cross(theta, w)
    return w - 0.5 * c + _cross(theta, c) / 12.0


def _reorthonormalize(R: Array) -> Array:
    """One Newton–Schulz polar step ``R ← R (3I − RᵀR)/2`` (B, 3, 3): removes accumulated rounding."""
    return 1.5 * R - 0.5 * R @ (np.swapaxes(R, -1, -2) @ R)

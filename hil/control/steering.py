"""VSCMG steering (Schaub, Vadali & Junkins 1998; Schaub & Junkins, *Analytical Mechanics of Space
Systems*): gimbal rates and rotor accelerations that deliver a required torque. Pure math, batched.

With unit i's spin and transverse axes ``sᵢ, tᵢ`` (body frame, at the current gimbal angle), spin inertia
``I_Wsᵢ`` and rotor speed ``Ωᵢ`` (relative to the gimbal), the array's momentum changes as::

    ḣ = Σ I_Wsᵢ Ω̇ᵢ sᵢ + Σ I_Wsᵢ Ωᵢ γ̇ᵢ tᵢ = [D₀ D₁] (Ω̇, γ̇) = Q η̇

and the body receives ``−ḣ``; to deliver the required torque L_r
(:class:`hil.control.attitude.AttitudeController`)
we need ``Q η̇ = −L_r``, solved by the weighted minimum-norm (pseudo-inverse) solution::

    η̇ = W Qᵀ (Q W Qᵀ)⁻¹ (−L_r),     W = diag(W_s₁ … W_sₙ, W_g₁ … W_gₙ)

The weights are made dimensionless by the nominal rotor speed Ω̄: ``W_sᵢ = W_s0 Ω̄² exp(−μ δ)``, so a
rotor acceleration of Ω̄ rad/s² costs what a gimbal rate of 1 rad/s does (both then change the momentum
by one h̄ per second) and W_s0 keeps the meaning of Schaub & Junkins' ratio. Without it the gimbal columns
of Q, Ω̄ times larger than the wheel columns, would win the minimum-norm solution even at a singularity.

with wheel weights ``W_sᵢ = W_s0 exp(−μ δ)`` and ``δ = det(D₁ D₁ᵀ / h̄²)`` (h̄ the nominal rotor momentum:
the determinant of the normalised matrix, as in Schaub & Junkins, so δ is dimensionless, of order one for
a well-conditioned array — 32/27 ≈ 1.19 for the 54.74° pyramid at zero gimbal angles — and 0 at a CMG
singularity). Away from singularities δ is large, the wheel weights
vanish and the array steers as CMGs (gimbal rates only: cheap in power); near one they grow and the
rotors take over as reaction wheels, so Q W Qᵀ stays invertible (D₀ has full rank for a non-coplanar
array) and the commands stay bounded.

Null motion (optional, ``null_gain`` > 0): ``η̇_N = k (I − W Qᵀ(QWQᵀ)⁻¹Q) W d`` changes nothing in ``Q η̇``
(the torque) while moving the gimbals along ``d = (−k_Ω (Ω − Ω_nom)/Ω_nom, ∂δ/∂γ)``, i.e. towards gimbal
sets of higher δ and rotor speeds back towards nominal.

Limits: rotors that would leave [min, max] speed within one control period lose their wheel weight
(re-solved without them, :attr:`Saturation.ROTOR_SPEED`); then the whole command is scaled by one factor
(the torque keeps its direction, falls short in size) so that every gimbal rate and rotor acceleration is
within its limit (:attr:`Saturation.GIMBAL_RATE`, :attr:`Saturation.ROTOR_ACCEL`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.vscmg import SpacecraftParams
from protocol.errors import ConfigError

Array = NDArray[np.float64]


class Saturation(enum.IntFlag):
    """What limited a steering command (per run, bits)."""

    NONE = 0
    GIMBAL_RATE = 1  # scaled down to the gimbal-rate limit
    ROTOR_ACCEL = 2  # scaled down to the rotor-acceleration limit
    ROTOR_SPEED = 4  # a rotor at a speed limit was taken out of wheel mode


@dataclass(frozen=True)
class SteeringParams:
    """``wheel_weight`` W_s0 (dimensionless, see the module docstring) and ``mu`` μ of the wheel weights,
    ``gimbal_weight`` W_g, ``null_gain`` k
    (1/s; 0 = no null motion), ``speed_gain`` k_Ω weighting the rotor-speed return in the null motion."""

    wheel_weight: float = 2.0
    mu: float = 10.0
    gimbal_weight: float = 1.0
    null_gain: float = 0.0
    speed_gain: float = 1.0

    def __post_init__(self) -> None:
        for name in ("wheel_weight", "mu", "gimbal_weight", "null_gain", "speed_gain"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"must be finite and non-negative, got {v!r}", f"SteeringParams.{name}")
        if self.gimbal_weight == 0:
            raise ConfigError("must be positive", "SteeringParams.gimbal_weight")


@dataclass(frozen=True)
class SteeringOutput:
    """Batch B, n units: ``gimbal_rate`` (B, n) rad/s and ``rotor_accel`` (B, n) rad/s² commands,
    ``torque`` (B, 3) N m the torque they deliver (−Q η̇), ``delta`` (B,) the singularity measure δ,
    ``wheel_weight`` (B, n), ``scale`` (B,) ≤ 1 the limit scaling, ``saturation`` (B,) :class:`Saturation`
    bits."""

    gimbal_rate: Array
    rotor_accel: Array
    torque: Array
    delta: Array
    wheel_weight: Array
    scale: Array
    saturation: NDArray[np.int64]


class VscmgSteering:
    """The weighted pseudo-inverse steering law for the array of ``params``."""

    def __init__(self, params: SpacecraftParams, steering: SteeringParams | None = None) -> None:
        self.params = params
        self.p = steering or SteeringParams()
        self.g = np.array([u.gimbal_axis for u in params.units], dtype=float)
        self.s0 = np.array([u.spin_axis for u in params.units], dtype=float)
        self.t0 = np.cross(self.g, self.s0)
        self.I_ws = np.array([u.rotor_spin_inertia for u in params.units])
        self.h_bar = params.nominal_wheel_momentum

    def axes(self, gimbal_angle: ArrayLike) -> tuple[Array, Array]:
        """Spin and transverse axes ``s, t`` (B, n, 3), body frame, at ``gimbal_angle`` (B, n)."""
        gam = np.asarray(gimbal_angle, dtype=float)
        c, s = np.cos(gam)[..., None], np.sin(gam)[..., None]
        return c * self.s0 + s * self.t0, c * self.t0 - s * self.s0

    def jacobians(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> tuple[Array, Array]:
        """``D₀`` and ``D₁`` (B, 3, n): ḣ per unit rotor acceleration and per unit gimbal rate."""
        s, t = self.axes(gimbal_angle)
        w = np.asarray(rotor_speed, dtype=float)
        D0 = np.swapaxes(self.I_ws[:, None] * s, -1, -2)
        D1 = np.swapaxes((self.I_ws * w)[..., None] * t, -1, -2)
        return D0, D1

    def momentum(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
        """The rotors' spin momentum ``Σ I_Wsᵢ Ωᵢ sᵢ`` (B, 3), body frame, N m s: the array momentum h as the
        controller's gyroscopic term needs it (gimbal-structure terms are orders smaller)."""
        s, _ = self.axes(np.atleast_2d(gimbal_angle))
        w = np.atleast_2d(np.asarray(rotor_speed, dtype=float))
        return np.einsum("bn,bni->bi", self.I_ws * w, s)

    def delta(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
        """The singularity measure ``δ = det(D₁ D₁ᵀ / h̄²)`` (B,): dimensionless, 0 at a CMG singularity."""
        _, D1 = self.jacobians(np.atleast_2d(gimbal_angle), np.atleast_2d(rotor_speed))
        return np.linalg.det(D1 @ np.swapaxes(D1, -1, -2)) / self.h_bar**6

    def delta_gradient(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
        """``∂δ/∂γ`` (B, n): ``2 (∂d₁ᵢ)ᵀ adj(A) d₁ᵢ / h̄⁶`` with ``A = D₁D₁ᵀ`` and ``∂d₁ᵢ/∂γᵢ = −I_Ws Ω sᵢ``
        (the adjugate keeps it finite at a singularity)."""
        s, t = self.axes(np.atleast_2d(gimbal_angle))
        w = np.atleast_2d(np.asarray(rotor_speed, dtype=float))
        d1 = (self.I_ws * w)[..., None] * t
        dd1 = -(self.I_ws * w)[..., None] * s
        A = np.einsum("bni,bnj->bij", d1, d1)
        adj = _adjugate(A)
        return 2.0 * np.einsum("bni,bij,bnj->bn", dd1, adj, d1) / self.h_bar**6

    def solve(
        self, torque: ArrayLike, gimbal_angle: ArrayLike, rotor_speed: ArrayLike, dt: float
    ) -> SteeringOutput:
        """Commands that deliver ``torque`` (B, 3) N m (the required array torque L_r, body frame) at the
        current ``gimbal_angle`` and ``rotor_speed`` (B, n); ``dt`` (s) is the control period over which a
        rotor must not leave its speed range. Unbatched inputs are taken as B = 1."""
        L = np.atleast_2d(np.asarray(torque, dtype=float))
        gam = np.atleast_2d(np.asarray(gimbal_angle, dtype=float))
        w = np.atleast_2d(np.asarray(rotor_speed, dtype=float))
        lim, p = self.params.limits, self.p
        n = self.g.shape[0]
        D0, D1 = self.jacobians(gam, w)
        Q = np.concatenate([D0, D1], axis=-1)
        delta = np.linalg.det(D1 @ np.swapaxes(D1, -1, -2)) / self.h_bar**6
        scale2 = self.params.nominal_rotor_speed**2
        ws = np.repeat((p.wheel_weight * scale2 * np.exp(-p.mu * delta))[:, None], n, axis=1)
        sat = np.zeros(L.shape[0], dtype=np.int64)
        eta = self._weighted(Q, ws, -L)
        # rotors about to leave their speed range lose wheel mode (one re-solve)
        ahead = w + eta[:, :n] * dt
        out = ((ahead > lim.max_rotor_speed) & (eta[:, :n] > 0)) | (
            (ahead < lim.min_rotor_speed) & (eta[:, :n] < 0)
        )
        if out.any():
            ws = np.where(out, 0.0, ws)
            eta = self._weighted(Q, ws, -L)
            sat |= np.where(out.any(axis=1), int(Saturation.ROTOR_SPEED), 0)
        if p.null_gain > 0:
            eta += self._null_motion(Q, ws, gam, w)
        # one scale factor for every limit
        g_ratio = np.max(np.abs(eta[:, n:]), axis=1) / lim.max_gimbal_rate
        a_ratio = np.max(np.abs(eta[:, :n]), axis=1) / lim.max_rotor_accel
        scale = 1.0 / np.maximum(1.0, np.maximum(g_ratio, a_ratio))
        sat |= np.where(g_ratio > 1.0, int(Saturation.GIMBAL_RATE), 0)
        sat |= np.where(a_ratio > 1.0, int(Saturation.ROTOR_ACCEL), 0)
        eta *= scale[:, None]
        delivered = -np.einsum("bij,bj->bi", Q, eta)
        return SteeringOutput(eta[:, n:], eta[:, :n], delivered, delta, ws, scale, sat)

    def _weighted(self, Q: Array, ws: Array, rhs: Array) -> Array:
        """``W Qᵀ (Q W Qᵀ)⁻¹ rhs`` (B, 2n)."""
        W = np.concatenate([ws, np.full_like(ws, self.p.gimbal_weight)], axis=1)
        QW = Q * W[:, None, :]
        lam = np.linalg.solve(QW @ np.swapaxes(Q, -1, -2), rhs[..., None])
        return (np.swapaxes(QW, -1, -2) @ lam)[..., 0]

    def _null_motion(self, Q: Array, ws: Array, gam: Array, w: Array) -> Array:
        """``k (W − W Qᵀ(QWQᵀ)⁻¹ Q W) d``: moves toward higher δ and nominal rotor speed, torque-free."""
        p = self.p
        nominal = self.params.nominal_rotor_speed
        d = np.concatenate([-p.speed_gain * (w - nominal) / nominal, self.delta_gradient(gam, w)], axis=1)
        W = np.concatenate([ws, np.full_like(ws, p.gimbal_weight)], axis=1)
        wd = W * d
        return p.null_gain * (wd - self._weighted(Q, ws, np.einsum("bij,bj->bi", Q, wd)))


def _adjugate(A: Array) -> Array:
    """Adjugate of (B, 3, 3) matrices (= det(A) A⁻¹ where A is invertible)."""
    c = np.empty_like(A)
    for i in range(3):
        for j in range(3):
            r = [k for k in range(3) if k != j]
            s = [k for k in range(3) if k != i]
            minor = A[:, r][:, :, s]
            c[:, i, j] = (-1) ** (i + j) * (minor[:, 0, 0] * minor[:, 1, 1] - minor[:, 0, 1] * minor[:, 1, 0])
    return c

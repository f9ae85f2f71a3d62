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
(the torque) while moving the gimbals along ``d = (−k_Ω (Ω − Ω_nom)/Ω̄², ∂δ/∂γ)``, i.e. towards gimbal
sets of higher δ and rotor speeds back towards nominal. The speed part is the gradient of
``½ k_Ω ((Ω − Ω_nom)/Ω̄)²`` with respect to Ω, so that with the wheel weight's Ω̄² a rotor off its nominal
speed is returned at ``k k_Ω W_s0 exp(−μ δ)`` per second (≤ 1/s at the defaults): slower than a rotor
drive answers (1/τ ≈ 7/s). Divided by Ω̄ only, it ran Ω̄ times faster — ~120/s on the air-bearing testbed,
whose tetrahedron sits at δ ≈ 0.07 in wheel mode — and the rotors' drives, lagging and unable to brake,
turned it into a limit cycle of the whole array in the hold (gimbals ±0.15 rad/s at ~1 Hz, rotor
commands ±80 rad/s², a 0.23° offset; docs/dynamics.md).

Limits: rotors that would leave [min, max] speed within one control period lose their wheel weight
(re-solved without them, :attr:`Saturation.ROTOR_SPEED`); then the whole command is scaled by one factor
(the torque keeps its direction, falls short in size) so that every gimbal rate and rotor acceleration is
within its limit (:attr:`Saturation.GIMBAL_RATE`, :attr:`Saturation.ROTOR_ACCEL`).

**No authority in some direction: damped least squares.** ``Q W Qᵀ`` is singular when the array can
deliver no torque about some axis with the weights in force: the rotors stopped (``D₁ = 0``: no gimbal
authority at all) and the speed rule above took the wheels that would have to slow below their minimum
out of wheel mode — the state of a board that has just reset while the host still steered (issue 16,
finding 1). The solve therefore uses ``(Q W Qᵀ + λ² I)⁻¹`` (Nakamura & Hanafusa's singularity-robust
inverse; Maciejewski & Klein's damping schedule): with ``σ`` the smallest eigenvalue of ``Q W Qᵀ`` and
``ε = singular_eps · h̄²``, ``λ² = damping · h̄² · (1 − σ/ε)²`` while ``σ < ε``, else 0. The damping is
continuous in the state, nil wherever the array has authority about every axis (every case above: at a CMG
singularity the wheels carry the missing axis, so ``σ`` stays of order ``W_s0 h̄²``), and bounds the
command in a direction without authority, where it delivers no torque instead of dividing by zero
(:attr:`Saturation.DAMPED`). No state of the array makes :meth:`VscmgSteering.solve` raise.

**Inputs with no finite command.** A torque above :data:`TORQUE_SCALED_ABOVE` (N m) is solved scaled
down to it, its direction kept: the limit scaling would cut its command to the same size, and the solve's
products would overflow from ~1e300 N m on (a command of NaN, flagged as nothing). A torque, gimbal angle
or rotor speed that is NaN or infinite, or a rotor speed so large that ``D₁ D₁ᵀ`` overflows (~1e150 rad/s),
has no finite command: the array is given none — gimbals still, rotor accelerations 0, scale 0 — flagged
:attr:`Saturation.NOT_FINITE` alone, instead of NaN commands flagged as nothing (which the wire refuses,
ending a run with ``ActuatorSetpoint.units[0].gimbal = nan is out of range``).
"""

from __future__ import annotations

import enum
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.jit import direct, kernel
from hil.vscmg import SpacecraftParams
from protocol.errors import ConfigError

Array = NDArray[np.float64]


class Saturation(enum.IntFlag):
    """What limited a steering command (per run, bits)."""

    NONE = 0
    GIMBAL_RATE = 1  # scaled down to the gimbal-rate limit
    ROTOR_ACCEL = 2  # scaled down to the rotor-acceleration limit
    ROTOR_SPEED = 4  # a rotor at a speed limit was taken out of wheel mode
    DAMPED = 8  # no authority about some axis: damped least squares (the module docstring)
    NOT_FINITE = 16  # no finite command for these inputs: none given (the module docstring)


@dataclass(frozen=True)
class SteeringParams:
    """``wheel_weight`` W_s0 (dimensionless, see the module docstring) and ``mu`` μ of the wheel weights,
    ``gimbal_weight`` W_g, ``null_gain`` k
    (1/s; 0 = no null motion), ``speed_gain`` k_Ω weighting the rotor-speed return in the null motion;
    ``singular_eps`` and ``damping`` (dimensionless, × h̄²) the damped least squares' threshold ε on the
    smallest eigenvalue of Q W Qᵀ and its largest damping λ² (the module docstring)."""

    wheel_weight: float = 2.0
    mu: float = 10.0
    gimbal_weight: float = 1.0
    null_gain: float = 0.0
    speed_gain: float = 1.0
    singular_eps: float = 1e-3
    damping: float = 1e-3

    def __post_init__(self) -> None:
        for name in (
            "wheel_weight",
            "mu",
            "gimbal_weight",
            "null_gain",
            "speed_gain",
            "singular_eps",
            "damping",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"must be finite and non-negative, got {v!r}", f"SteeringParams.{name}")
        for name in ("gimbal_weight", "singular_eps", "damping"):
            if getattr(self, name) == 0:
                raise ConfigError("must be positive", f"SteeringParams.{name}")


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

    @classmethod
    def empty(cls, b: int, n: int) -> SteeringOutput:
        """Uninitialised arrays for ``b`` rows of ``n`` units (C-contiguous), as :func:`solve_rows` fills."""
        return cls(
            np.empty((b, n)),
            np.empty((b, n)),
            np.empty((b, 3)),
            np.empty(b),
            np.empty((b, n)),
            np.empty(b),
            np.empty(b, np.int64),
        )

    def kernel_outputs(self) -> tuple[np.ndarray, ...]:
        """The arrays in :func:`solve_rows`'s order of outputs (the fields' order)."""
        return (
            self.gimbal_rate,
            self.rotor_accel,
            self.torque,
            self.delta,
            self.wheel_weight,
            self.scale,
            self.saturation,
        )


class VscmgSteering:
    """The weighted pseudo-inverse steering law for the array of ``params``: :meth:`solve`, :meth:`delta`
    and :meth:`delta_gradient` run compiled kernels (:func:`solve_rows`), one call per batch;
    :mod:`hil.control.steering_reference` is their numpy reference. :meth:`momentum` too (a kernel for
    the host's every control tick; its numpy form, from :meth:`axes`, is in the tests)."""

    def __init__(self, params: SpacecraftParams, steering: SteeringParams | None = None) -> None:
        self.params = params
        self.p = steering or SteeringParams()
        self.g = np.array([u.gimbal_axis for u in params.units], dtype=float)
        self.s0 = np.array([u.spin_axis for u in params.units], dtype=float)
        self.t0 = np.cross(self.g, self.s0)
        self.I_ws = np.array([u.rotor_spin_inertia for u in params.units])
        self.h_bar = params.nominal_wheel_momentum
        if not self.h_bar**6 >= sys.float_info.min:  # the kernels scale by h̄⁶: 0 was a ZeroDivisionError
            raise ConfigError(
                f"a nominal wheel momentum of {self.h_bar!r} N m s is too small to steer by (its sixth "
                "power underflows): VSCMG steering needs spinning rotors",
                "SpacecraftParams.nominal_rotor_speed",
            )
        self._kp, self._geom = pack(self)
        self._one: _OneRow | None = None  # the control tick's scratch and kernels (:meth:`_row`)

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
        gam, w = self._rows(gimbal_angle), self._rows(rotor_speed)
        out = np.empty((gam.shape[0], 3))
        momentum_rows(self._geom, gam, w, out)
        return out

    def delta(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
        """The singularity measure ``δ = det(D₁ D₁ᵀ / h̄²)`` (B,): dimensionless, 0 at a CMG singularity."""
        gam, w = self._rows(gimbal_angle), self._rows(rotor_speed)
        out = np.empty(gam.shape[0])
        delta_rows(self._kp, self._geom, gam, w, out)
        return out

    def delta_gradient(self, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
        """``∂δ/∂γ`` (B, n): ``2 (∂d₁ᵢ)ᵀ adj(A) d₁ᵢ / h̄⁶`` with ``A = D₁D₁ᵀ`` and ``∂d₁ᵢ/∂γᵢ = −I_Ws Ω sᵢ``
        (the adjugate keeps it finite at a singularity)."""
        gam, w = self._rows(gimbal_angle), self._rows(rotor_speed)
        out = np.empty_like(gam)
        for b in range(gam.shape[0]):
            delta_gradient_row(self._kp, self._geom, gam[b], w[b], out[b])
        return out

    def solve(
        self, torque: ArrayLike, gimbal_angle: ArrayLike, rotor_speed: ArrayLike, dt: float
    ) -> SteeringOutput:
        """Commands that deliver ``torque`` (B, 3) N m (the required array torque L_r, body frame) at the
        current ``gimbal_angle`` and ``rotor_speed`` (B, n); ``dt`` (s) is the control period over which a
        rotor must not leave its speed range. Unbatched inputs are taken as B = 1."""
        L, gam, w = self._rows(torque), self._rows(gimbal_angle), self._rows(rotor_speed)
        out = SteeringOutput.empty(*gam.shape)
        solve_rows(*self._solve_arguments(L, gam, w, dt, out))
        return out

    def _solve_arguments(
        self, torque: Array, gimbal_angle: Array, rotor_speed: Array, dt: float, out: SteeringOutput
    ) -> tuple[Any, ...]:
        """:func:`solve_rows`'s arguments (its batched call, its direct entry's examples and calls): the one
        place that spells their order."""
        return (self._kp, self._geom, torque, gimbal_angle, rotor_speed, float(dt), *out.kernel_outputs())

    def momentum_one(
        self, gimbal_angle: Sequence[float], rotor_speed: Sequence[float]
    ) -> tuple[float, float, float]:
        """:meth:`momentum` for one row (the control tick's): ``gimbal_angle`` rad and ``rotor_speed``
        rad/s, n values each (floats, or a (n,) array), the momentum (N m s, body frame) as three floats.
        The same kernel on the same float64 values, so the same bits, called without numba's dispatch
        into arrays kept for it (:class:`_OneRow`)."""
        one = self._row(gimbal_angle, rotor_speed)
        one.momentum(self._geom, one.gam, one.w, one.h)
        x, y, z = one.h[0].tolist()
        return x, y, z

    def solve_one(
        self,
        torque: Sequence[float],
        gimbal_angle: Sequence[float],
        rotor_speed: Sequence[float],
        dt: float,
    ) -> tuple[list[float], list[float], float]:
        """:meth:`solve` for one row (the control tick's): ``torque`` three floats (N m), ``gimbal_angle``
        rad and ``rotor_speed`` rad/s n values each, ``dt`` s. Returns the gimbal rates (rad/s) and rotor
        accelerations (rad/s²) as lists of n floats and δ: :meth:`solve`'s ``gimbal_rate[0]``,
        ``rotor_accel[0]`` and ``delta[0]``, bit for bit (the same kernel, without numba's dispatch, into
        arrays kept for it; the rest of :class:`SteeringOutput` is not made)."""
        one = self._row(gimbal_angle, rotor_speed)
        if len(torque) != 3:
            raise ValueError(f"torque: {len(torque)} values for 3")
        one.torque[0] = torque
        out = one.out
        one.solve(*self._solve_arguments(one.torque, one.gam, one.w, dt, out))
        return out.gimbal_rate[0].tolist(), out.rotor_accel[0].tolist(), out.delta.item()

    def _row(self, gimbal_angle: Sequence[float], rotor_speed: Sequence[float]) -> _OneRow:
        """The one-row scratch (made at the first call) holding ``gimbal_angle`` and ``rotor_speed``
        (n values each: ValueError otherwise, a single value included, which numpy would broadcast)."""
        one = self._one
        if one is None:
            one = self._one = _OneRow(self)
        if len(gimbal_angle) != one.n or len(rotor_speed) != one.n:
            raise ValueError(
                f"{len(gimbal_angle)} gimbal angles and {len(rotor_speed)} rotor speeds for {one.n} units"
            )
        one.gam[0] = gimbal_angle
        one.w[0] = rotor_speed
        return one

    def _rows(self, a: ArrayLike) -> Array:
        """``a`` as a C-contiguous float array of at least two dimensions (B, ...), copied only if it is
        not one: one numpy call (atleast_2d and ascontiguousarray cost ~0.3 µs each, every control tick)."""
        return np.array(a, dtype=float, ndmin=2, copy=None, order="C")


class _OneRow:
    """The arrays one row of :meth:`VscmgSteering.momentum_one` and :meth:`~VscmgSteering.solve_one` go
    through — inputs (1, n), (1, 3) and :class:`SteeringOutput`'s fields for B = 1, all C-contiguous
    float64 (int64 for the saturation bits) — and the kernels compiled for exactly those types
    (:func:`hil.jit.direct`). The direct entry points do not check their arguments' types: only these
    arrays go in. Made once per steering law; every control tick reuses them (no array is made per
    tick, and numba's dispatcher does not type 13 arguments to pick the version it already has)."""

    def __init__(self, steer: VscmgSteering) -> None:
        n = self.n = len(steer.params.units)
        self.gam, self.w = np.empty((1, n)), np.empty((1, n))
        self.torque, self.h = np.empty((1, 3)), np.empty((1, 3))
        self.out = SteeringOutput.empty(1, n)
        self.momentum: Callable[..., Any] = direct(momentum_rows, steer._geom, self.gam, self.w, self.h)
        self.solve: Callable[..., Any] = direct(
            solve_rows, *steer._solve_arguments(self.torque, self.gam, self.w, 0.0, self.out)
        )


# --------------------------------------------------------------------------- kernels
K_WHEEL = 0  # W_s0 Ω̄²: the wheel weight before exp(−μ δ)
K_MU = 1  # μ
K_GIMBAL = 2  # W_g
K_NULL = 3  # k (1/s), 0: no null motion
K_SPEED = 4  # k_Ω
K_NOMINAL = 5  # Ω̄ (rad/s)
K_HBAR6 = 6  # h̄⁶
K_MAX_SPEED = 7  # rad/s
K_MIN_SPEED = 8  # rad/s
K_MAX_GIMBAL_RATE = 9  # rad/s
K_MAX_ROTOR_ACCEL = 10  # rad/s²
K_EPS = 11  # ε = singular_eps h̄²: below this smallest eigenvalue of Q W Qᵀ the solve is damped
K_DAMPING = 12  # damping h̄²: λ² where the smallest eigenvalue is 0
K_SIZE = 13
"""The kernels' parameter array (float64); the geometry array is (n, 7): ``s0`` (3), ``t0`` (3), I_Ws."""

TORQUE_SCALED_ABOVE = 1e100
"""N m: a larger required torque is solved scaled down to this size, its direction kept (the module
docstring); far above anything an array delivers, far below where the solve's products overflow."""

_NOT_FINITE = int(Saturation.NOT_FINITE)
_ROTOR_SPEED = int(Saturation.ROTOR_SPEED)
_GIMBAL_RATE = int(Saturation.GIMBAL_RATE)
_ROTOR_ACCEL = int(Saturation.ROTOR_ACCEL)
_DAMPED = int(Saturation.DAMPED)


def pack(steer: VscmgSteering) -> tuple[Array, Array]:
    """The kernels' parameter array (:data:`K_SIZE`) and geometry array (n, 7) for ``steer``."""
    p, lim = steer.p, steer.params.limits
    kp = np.zeros(K_SIZE)
    kp[K_WHEEL] = p.wheel_weight * steer.params.nominal_rotor_speed**2
    kp[K_MU], kp[K_GIMBAL], kp[K_NULL], kp[K_SPEED] = p.mu, p.gimbal_weight, p.null_gain, p.speed_gain
    kp[K_NOMINAL] = steer.params.nominal_rotor_speed
    kp[K_HBAR6] = steer.h_bar**6
    kp[K_MAX_SPEED], kp[K_MIN_SPEED] = lim.max_rotor_speed, lim.min_rotor_speed
    kp[K_MAX_GIMBAL_RATE], kp[K_MAX_ROTOR_ACCEL] = lim.max_gimbal_rate, lim.max_rotor_accel
    kp[K_EPS], kp[K_DAMPING] = p.singular_eps * steer.h_bar**2, p.damping * steer.h_bar**2
    geom = np.ascontiguousarray(np.column_stack([steer.s0, steer.t0, steer.I_ws]))
    return kp, geom


@kernel
def adjugate3(a0, a1, a2, a3, a4, a5, a6, a7, a8):  # type: ignore[no-untyped-def]
    """Adjugate of a row-major 3×3 matrix (= det(A) A⁻¹ where A is invertible), a row-major 9-tuple."""
    return (
        a4 * a8 - a5 * a7, a2 * a7 - a1 * a8, a1 * a5 - a2 * a4,
        a5 * a6 - a3 * a8, a0 * a8 - a2 * a6, a2 * a3 - a0 * a5,
        a3 * a7 - a4 * a6, a1 * a6 - a0 * a7, a0 * a4 - a1 * a3,
    )  # fmt: skip


@kernel
def _axes(geom, gam, s, t):  # type: ignore[no-untyped-def]
    """Spin and transverse axes (n, 3) at gimbal angles ``gam`` (n,)."""
    for i in range(gam.shape[0]):
        c, sn = math.cos(gam[i]), math.sin(gam[i])
        for j in range(3):
            s[i, j] = c * geom[i, j] + sn * geom[i, 3 + j]
            t[i, j] = c * geom[i, 3 + j] - sn * geom[i, j]


@kernel
def _d1_gram(geom, w, t):  # type: ignore[no-untyped-def]
    """``A = D₁ D₁ᵀ`` (row-major 9-tuple), ``D₁``'s columns being ``I_Ws Ωᵢ tᵢ``."""
    a = np.zeros(9)
    for i in range(w.shape[0]):
        k = geom[i, 6] * w[i]
        for r in range(3):
            for c in range(3):
                a[3 * r + c] += (k * t[i, r]) * (k * t[i, c])
    return a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8]


@kernel
def momentum_rows(geom, gam, w, out):  # type: ignore[no-untyped-def]
    """``Σ I_Wsᵢ Ωᵢ sᵢ`` (B, 3) for B rows of ``gam`` and ``w`` (B, n) into ``out`` (see
    :meth:`VscmgSteering.momentum`)."""
    n = gam.shape[1]
    s, t = np.empty((n, 3)), np.empty((n, 3))
    for b in range(gam.shape[0]):
        _axes(geom, gam[b], s, t)
        for r in range(3):
            acc = 0.0
            for i in range(n):
                acc += (geom[i, 6] * w[b, i]) * s[i, r]
            out[b, r] = acc


@kernel
def _delta(kp, geom, w, t):  # type: ignore[no-untyped-def]
    """``δ = det(D₁ D₁ᵀ) / h̄⁶`` for one row, the transverse axes ``t`` (n, 3) computed."""
    a = _d1_gram(geom, w, t)
    det = (
        a[0] * (a[4] * a[8] - a[5] * a[7])
        - a[1] * (a[3] * a[8] - a[5] * a[6])
        + a[2] * (a[3] * a[7] - a[4] * a[6])
    )
    return det / kp[K_HBAR6]


@kernel
def delta_rows(kp, geom, gam, w, out):  # type: ignore[no-untyped-def]
    """``δ`` (B,) for B rows of ``gam`` and ``w`` (B, n) into ``out`` (see :meth:`VscmgSteering.delta`)."""
    n = gam.shape[1]
    s, t = np.empty((n, 3)), np.empty((n, 3))
    for b in range(gam.shape[0]):
        _axes(geom, gam[b], s, t)
        out[b] = _delta(kp, geom, w[b], t)


@kernel
def delta_gradient_row(kp, geom, gam, w, out):  # type: ignore[no-untyped-def]
    """``∂δ/∂γ`` (n,) for one row into ``out`` (see :meth:`VscmgSteering.delta_gradient`)."""
    n = gam.shape[0]
    s, t = np.empty((n, 3)), np.empty((n, 3))
    _axes(geom, gam, s, t)
    _delta_gradient(kp, geom, w, s, t, out)


@kernel
def _delta_gradient(kp, geom, w, s, t, out):  # type: ignore[no-untyped-def]
    adj = adjugate3(*_d1_gram(geom, w, t))
    for i in range(w.shape[0]):
        k = geom[i, 6] * w[i]
        acc = 0.0
        for r in range(3):
            row = adj[3 * r] * (k * t[i, 0]) + adj[3 * r + 1] * (k * t[i, 1]) + adj[3 * r + 2] * (k * t[i, 2])
            acc += -(k * s[i, r]) * row
        out[i] = 2.0 * acc / kp[K_HBAR6]


@kernel
def _solve3(m, rhs, x):  # type: ignore[no-untyped-def]
    """``x = m⁻¹ rhs`` for a 3×3 ``m`` by Gaussian elimination with partial pivoting (as LAPACK's gesv);
    ``m`` and ``rhs`` are overwritten."""
    for c in range(3):
        p = c
        for r in range(c + 1, 3):
            if abs(m[r, c]) > abs(m[p, c]):
                p = r
        if p != c:
            for j in range(3):
                m[c, j], m[p, j] = m[p, j], m[c, j]
            rhs[c], rhs[p] = rhs[p], rhs[c]
        for r in range(c + 1, 3):
            f = m[r, c] / m[c, c]
            for j in range(c, 3):
                m[r, j] -= f * m[c, j]
            rhs[r] -= f * rhs[c]
    for r in range(2, -1, -1):
        acc = rhs[r]
        for j in range(r + 1, 3):
            acc -= m[r, j] * x[j]
        x[r] = acc / m[r, r]


@kernel
def min_eigenvalue_sym3(a00, a01, a02, a11, a12, a22):  # type: ignore[no-untyped-def]
    """The smallest eigenvalue of a symmetric 3×3 matrix, in closed form (Smith 1961: the roots of its
    characteristic polynomial by the trigonometric formula); absolute error ~1e-16 × its trace (~1e-8 × it
    at a repeated eigenvalue, where the formula's arccosine is ill-conditioned).

    Defined for every finite matrix (a compiled kernel's division by zero raises where numpy gives inf: a
    rotor a hair from rest once stopped the control tick with a ZeroDivisionError). A matrix whose entries
    would overflow the formula's squares is solved scaled by its largest entry; one whose deviation from a
    multiple of the identity is so small that its scale cubed would be subnormal takes the determinant of the
    scaled deviation. Any other matrix gets the plain formula, bit for bit as before."""
    big = max(abs(a00), abs(a01), abs(a02), abs(a11), abs(a12), abs(a22))
    if big > _EIGEN_SCALED_ABOVE:
        return big * _min_eigenvalue(a00 / big, a01 / big, a02 / big, a11 / big, a12 / big, a22 / big)
    return _min_eigenvalue(a00, a01, a02, a11, a12, a22)


_EIGEN_SCALED_ABOVE = 1e100
"""Entries above which :func:`min_eigenvalue_sym3` scales the matrix (its squares' sums stay finite below)."""
_EIGEN_PLAIN_ABOVE = 1e-100
"""The deviation's scale ``p`` above which the formula's ``p³`` is a normal float (full precision)."""


@kernel
def _min_eigenvalue(a00, a01, a02, a11, a12, a22):  # type: ignore[no-untyped-def]
    """:func:`min_eigenvalue_sym3` for entries of magnitude at most :data:`_EIGEN_SCALED_ABOVE`."""
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    if p2 <= 0.0:
        return q  # a multiple of the identity
    p = math.sqrt(p2 / 6.0)
    if p == 0.0:  # p2 itself subnormal: within ~1e-162 of a multiple of the identity
        return q
    if p > _EIGEN_PLAIN_ABOVE:
        det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
        r = det / (2.0 * p * p * p)
    else:  # p³ would be subnormal or 0: the determinant of (A − qI)/p instead, each entry divided first
        c00, c11, c22, c01, c02, c12 = b00 / p, b11 / p, b22 / p, a01 / p, a02 / p, a12 / p
        r = 0.5 * (
            c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02) + c02 * (c01 * c12 - c11 * c02)
        )
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)


@kernel
def _weighted(q, wt, rhs, out, m, lam, kp):  # type: ignore[no-untyped-def]
    """``out = W Qᵀ (Q W Qᵀ + λ² I)⁻¹ rhs`` (2n,) for ``q`` (3, 2n), weights ``wt`` (2n,), λ² from the
    smallest eigenvalue of Q W Qᵀ (the module docstring); ``m`` (3, 3) and ``lam`` (3,) are scratch,
    ``rhs`` (3,) is overwritten. Returns λ² (0: undamped)."""
    cols = q.shape[1]
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for c in range(cols):
                acc += (q[i, c] * wt[c]) * q[j, c]
            m[i, j] = acc
    sigma = min_eigenvalue_sym3(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
    damp = 0.0
    if sigma < kp[K_EPS]:
        k = 1.0 - max(sigma, 0.0) / kp[K_EPS]
        damp = kp[K_DAMPING] * k * k
        for i in range(3):
            m[i, i] += damp
    _solve3(m, rhs, lam)
    for c in range(cols):
        out[c] = (q[0, c] * wt[c]) * lam[0] + (q[1, c] * wt[c]) * lam[1] + (q[2, c] * wt[c]) * lam[2]
    return damp


@kernel
def _torque_rhs(torque, rhs):  # type: ignore[no-untyped-def]
    """``rhs = −torque`` (3,), scaled down to :data:`TORQUE_SCALED_ABOVE` where it is larger (the module
    docstring); an infinite component makes the whole right-hand side NaN (∞ · 0), as a NaN one does."""
    big = max(abs(torque[0]), abs(torque[1]), abs(torque[2]))
    if big > TORQUE_SCALED_ABOVE:
        k = TORQUE_SCALED_ABOVE / big
        for r in range(3):
            rhs[r] = -torque[r] * k
    else:
        for r in range(3):
            rhs[r] = -torque[r]


@kernel
def solve_rows(
    kp, geom, torque, gam, w, dt, gimbal_rate, rotor_accel, delivered, delta, wheel_weight, scale, sat
):  # type: ignore[no-untyped-def]
    """:meth:`VscmgSteering.solve` for B rows: ``torque`` (B, 3), ``gam`` and ``w`` (B, n) in; the
    outputs (``SteeringOutput``'s fields, same shapes) written in place."""
    b_rows, n = gam.shape
    s, t = np.empty((n, 3)), np.empty((n, 3))
    q = np.empty((3, 2 * n))
    wt, eta, extra, d = np.empty(2 * n), np.empty(2 * n), np.empty(2 * n), np.empty(2 * n)
    m, lam, rhs = np.empty((3, 3)), np.empty(3), np.empty(3)
    for b in range(b_rows):
        _axes(geom, gam[b], s, t)
        for i in range(n):
            for r in range(3):
                q[r, i] = geom[i, 6] * s[i, r]
                q[r, n + i] = (geom[i, 6] * w[b, i]) * t[i, r]
        delta[b] = _delta(kp, geom, w[b], t)
        ws = kp[K_WHEEL] * math.exp(-kp[K_MU] * delta[b])
        for i in range(n):
            wt[i] = ws
            wt[n + i] = kp[K_GIMBAL]
        _torque_rhs(torque[b], rhs)
        damped = _weighted(q, wt, rhs, eta, m, lam, kp)
        flags = 0
        out_any = False  # rotors about to leave their speed range lose wheel mode (one re-solve)
        for i in range(n):
            ahead = w[b, i] + eta[i] * dt
            if (ahead > kp[K_MAX_SPEED] and eta[i] > 0) or (ahead < kp[K_MIN_SPEED] and eta[i] < 0):
                wt[i] = 0.0
                out_any = True
        if out_any:
            _torque_rhs(torque[b], rhs)
            damped = _weighted(q, wt, rhs, eta, m, lam, kp)
            flags |= _ROTOR_SPEED
        if damped > 0.0:  # the solve that stands (the re-solve if there was one) was damped
            flags |= _DAMPED
        if kp[K_NULL] > 0:  # k (W d − W Qᵀ(QWQᵀ)⁻¹ Q W d): toward higher δ and nominal rotor speed
            nominal = kp[K_NOMINAL]
            for i in range(n):  # the gradient of ½ k_Ω ((Ω − Ω_nom)/Ω̄)²: W's Ω̄² makes it 1/s
                d[i] = -kp[K_SPEED] * (w[b, i] - nominal) / (nominal * nominal)
            _delta_gradient(kp, geom, w[b], s, t, d[n:])
            for c in range(2 * n):
                d[c] *= wt[c]
            for r in range(3):
                acc = 0.0
                for c in range(2 * n):
                    acc += q[r, c] * d[c]
                rhs[r] = acc
            _weighted(q, wt, rhs, extra, m, lam, kp)
            for c in range(2 * n):
                eta[c] += kp[K_NULL] * (d[c] - extra[c])
        g_max = a_max = 0.0  # one scale factor for every limit
        finite = True
        for i in range(n):
            a_max = max(a_max, abs(eta[i]))
            g_max = max(g_max, abs(eta[n + i]))
            finite = finite and math.isfinite(eta[i]) and math.isfinite(eta[n + i])
        g_ratio, a_ratio = g_max / kp[K_MAX_GIMBAL_RATE], a_max / kp[K_MAX_ROTOR_ACCEL]
        k = 1.0 / max(1.0, max(g_ratio, a_ratio))
        if g_ratio > 1.0:
            flags |= _GIMBAL_RATE
        if a_ratio > 1.0:
            flags |= _ROTOR_ACCEL
        if not finite:  # no finite command for these inputs: none (the module docstring)
            k = 0.0
            flags = _NOT_FINITE
            for c in range(2 * n):
                eta[c] = 0.0
        for i in range(n):
            rotor_accel[b, i] = eta[i] * k
            gimbal_rate[b, i] = eta[n + i] * k
            wheel_weight[b, i] = wt[i]
        for r in range(3):
            acc = 0.0
            if finite:  # else no command, no torque (Q itself may be NaN: 0 · NaN)
                for c in range(2 * n):
                    acc += q[r, c] * (eta[c] * k)
            delivered[b, r] = -acc
        scale[b] = k
        sat[b] = flags

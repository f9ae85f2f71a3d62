"""The paper's second-order discrete variational attitude estimator (Viswanathan, Sanyal & Izadi,
arXiv 1509.03677, Proposition 1; Izadi & Sanyal, Automatica 2014). Pure math, no I/O.

Notation (docs/estimator.md derives each line): ``Ω^m`` measured body rate (rad/s), ``ω`` the rate-estimate
error, ``Ω̂ = Ω^m − ω`` the rate estimate, ``R̂`` the attitude estimate (body → inertial ENU), ``h`` the step::

    R̂[i+1]   = R̂[i] exp(h (Ω^m[i+½] − ω[i+½])^×),            Ω^m[i+½] = (Ω^m[i] + Ω^m[i+1]) / 2
    ω[i+½]   = (m I + h/2 D)⁻¹ { exp(−h/2 Ω̂[i]^×) m ω[i] + h/2 Φ'(U⁰[i]) S_L[i] }
    m ω[i+1] = exp(−h/2 Ω̂[i+1]^×) { (m I − h/2 D) ω[i+½] + h/2 Φ'(U⁰[i+1]) S_L[i+1] }
    S_L(R̂)  = vex(Lᵀ R̂ − R̂ᵀ L),  L = E W Uᵀ,  U⁰ = ½ ⟨E − R̂ U, (E − R̂ U) W⟩

``E = [e1 e2 e1×e2]`` holds the inertial directions (e1: the accelerometer's reading of gravity, i.e. *up*;
e2: the geomagnetic field direction), ``U = [u1 u2 u1×u2]`` the measured ones in the body frame (unit
accelerometer and magnetometer vectors); third columns are normalised cross products.

The last line is implicit in ``ω[i+1]`` (``Ω̂[i+1] = Ω^m[i+1] − ω[i+1]``). With ``c`` its braced right-hand
side and ``φ(ω) = h/2 (ω − Ω^m[i+1])`` it reads ``f(ω) = m ω − exp(φ^×) c = 0``, solved by Newton–Raphson
with the analytic Jacobian ``∂f/∂ω = m I + h/2 y^× J_l(φ)``, ``y = exp(φ^×) c`` and ``J_l`` the left
Jacobian of SO(3), from one fixed-point pass ``ω = exp(φ(c/m)^×) c / m``. Iteration stops when the
residual satisfies ``‖f‖ / m ≤ newton_tol · √(1 + ‖ω‖²)`` (default 1e-12 rad/s; ``‖f‖/m`` is the size of
the next Newton update to O(h)); after ``newton_max_iter`` updates (default 10) the step is a failure:
flagged :attr:`StepFlag.NEWTON_FAILED` and counted, or raised as :class:`ConvergenceError`
(``on_newton_failure``). At phone rates one update suffices (quadratic convergence from an O(h²) start).

Missing measurements: a direction that is not usable (None/NaN input, a stale sensor) is left out of the
potential: ``L = E_S W_SS U_Sᵀ`` over the usable set S ⊆ {acc, mag, acc×mag} (the cross-product column
needs both, and is dropped when they are within ``min_direction_angle_deg`` of parallel). With no usable
direction the potential term vanishes and the filter propagates the gyro. A gyroscope that is not usable
is read as a zero rate measurement (the filter then runs on the vector measurements alone, ``Ω̂ = −ω``).

Long steps: the scheme's discrete dissipation factor ``(m − h/2 d)/(m + h/2 d)`` turns negative (a
ringing, though bounded, rate error) once ``h > 2m/d``; steps longer than ``max_step_s`` are therefore
split into equal sub-steps with the gyro interpolated linearly and the new measurement held
(:attr:`StepFlag.SUBSTEPPED`).

R̂ stays a rotation: each step multiplies by an exact rotation (Rodrigues) and applies one Newton–Schulz
polar correction, which keeps ``‖R̂ᵀR̂ − I‖`` at rounding level however many steps are taken.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import astuple, dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.prefilter import PAPER_CUTOFF_RAD_S, GateSettings, MagneticGate, SignalPrefilter
from hil.estimation.sensors import KINDS, MergedStep, MergedSteps, SensorKind, StepFlag, as_vec3
from hil.so3 import Mat9, Vec3, matmul_f, reorthonormalize_f, rodrigues_coefficients, rotate_f, solve3_f
from protocol.errors import ConfigError, ConvergenceError

Array = NDArray[np.float64]

_ACC, _MAG, _CROSS = 1, 2, 4  # bits of the usable-direction mask (index into per-mask tables)


# --------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Potential:
    """The shaping function Φ of the potential (C², Φ(0) = 0, Φ' > 0): the filter uses ``Φ'(U⁰)``.

    ``constant_derivative`` is set when Φ' does not depend on U⁰ (Φ linear), which spares computing U⁰.
    """

    name: str
    value: Callable[[float], float]
    derivative: Callable[[float], float]
    constant_derivative: float | None = None


PHI_IDENTITY = Potential("identity", lambda x: x, lambda x: 1.0, 1.0)
"""The paper's choice, Φ(x) = x."""


def phi_log(scale: float) -> Potential:
    """``Φ(x) = s ln(1 + x/s)``: gain ``Φ' = 1/(1 + x/s)`` falls for large errors (less overshoot after a
    bad start or a disturbed magnetometer), and equals the identity's near convergence."""
    if not scale > 0:
        raise ConfigError(f"log potential scale must be positive, got {scale!r}", "phi_log")
    return Potential(
        f"log({scale:g})", lambda x: scale * math.log1p(x / scale), lambda x: 1.0 / (1.0 + x / scale)
    )


PAPER_E = ((0.0, 0.0772, -0.9921), (0.0, 0.6117, 0.1251), (1.0, -0.7873, 0.0))
PAPER_W = ((3.19, 1.51, 0.0), (1.51, 3.19, 0.0), (0.0, 0.0, 2.0))
PAPER_M = 0.5
PAPER_D = ((12.0, 0.0, 0.0), (0.0, 13.0, 0.0), (0.0, 0.0, 14.0))
PAPER_Q0_ROTVEC = (2.2 * 0.63, 2.2 * 0.62, -2.2 * 0.48)
"""Rotation vector of the paper's initial estimate error ``Q0 = R R̂ᵀ`` (≈127°)."""
PAPER_OMEGA0 = (0.001, 0.002, -0.003)
"""The paper's initial rate-estimate error ω0 (rad/s)."""


def directions_matrix(e_acc: ArrayLike, e_mag: ArrayLike) -> Array:
    """``E = [e1 e2 e1×e2/|e1×e2|]`` (3, 3) from the inertial directions of the accelerometer reading (up)
    and of the magnetic field; both are normalised. Raises ConfigError if they are (nearly) parallel."""
    e1 = _unit(e_acc, "e_acc")
    e2 = _unit(e_mag, "e_mag")
    c = np.cross(e1, e2)
    n = float(np.linalg.norm(c))
    if n < 1e-3:
        raise ConfigError("inertial directions are parallel: their cross product is undefined", "E")
    return np.column_stack([e1, e2, c / n])


def _unit(v: ArrayLike, where: str) -> Array:
    a = np.asarray(v, dtype=float).reshape(-1)
    n = float(np.linalg.norm(a)) if a.shape == (3,) else math.nan
    if not (math.isfinite(n) and n > 0):
        raise ConfigError(f"needs a non-zero finite 3-vector, got {v!r}", where)
    return a / n


def _matrix(value: ArrayLike, where: str) -> Array:
    a = np.asarray(value, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ConfigError(f"must be a finite 3x3 matrix, got {np.asarray(value).tolist()!r}", where)
    if not np.allclose(a, a.T, rtol=0, atol=1e-12 * max(1.0, float(np.abs(a).max()))):
        raise ConfigError(f"must be symmetric, got {a.tolist()!r}", where)
    return a


@dataclass(frozen=True)
class EstimatorParams:
    """Gains and numerics of the estimator.

    ``E`` (3, 3): inertial (ENU) directions ``[e1 e2 e1×e2]`` — e1 the accelerometer's gravity reading
    (up), e2 the unit geomagnetic field; columns are normalised and the third is checked against (and
    replaced by) the normalised cross product. ``W`` (3, 3) symmetric weights: ``E W Eᵀ`` must be positive
    definite with distinct eigenvalues (U⁰ is then a Morse function on SO(3) with an almost-global basin).
    ``m`` > 0 (the estimator's 'inertia'), ``D`` (3, 3) symmetric positive definite (its 'dissipation').
    """

    E: Array = field(default_factory=lambda: np.array(PAPER_E))
    W: Array = field(default_factory=lambda: np.array(PAPER_W))
    m: float = PAPER_M
    D: Array = field(default_factory=lambda: np.array(PAPER_D))
    phi: Potential = PHI_IDENTITY
    newton_tol: float = 1e-12
    newton_max_iter: int = 10
    on_newton_failure: Literal["flag", "raise"] = "flag"
    max_step_s: float = 0.05
    min_direction_angle_deg: float = 2.0

    def __post_init__(self) -> None:
        e = np.asarray(self.E, dtype=float)
        if e.shape != (3, 3) or not np.all(np.isfinite(e)):
            raise ConfigError("must be a finite 3x3 matrix of column directions", "EstimatorParams.E")
        norms = np.linalg.norm(e, axis=0)
        if np.any(np.abs(norms - 1.0) > 1e-2):
            raise ConfigError(f"columns must be unit vectors, norms are {norms.round(4).tolist()}", "E")
        e_full = directions_matrix(e[:, 0], e[:, 1])
        if np.linalg.norm(e_full[:, 2] - e[:, 2] / norms[2]) > 1e-2:
            expected = e_full[:, 2].round(4).tolist()
            raise ConfigError(f"third column {e[:, 2].tolist()} is not e1×e2/|e1×e2| = {expected}", "E")
        w = _matrix(self.W, "EstimatorParams.W")
        lam = np.linalg.eigvalsh(e_full @ w @ e_full.T)
        if lam[0] <= 0.0:
            raise ConfigError(f"E W Eᵀ must be positive definite; its eigenvalues are {lam.tolist()}", "W")
        if np.min(np.diff(lam)) <= 1e-6 * lam[-1]:
            raise ConfigError(
                f"E W Eᵀ must have distinct eigenvalues (else U⁰ is not a Morse function and the filter "
                f"has a continuum of equilibria); its eigenvalues are {lam.tolist()}",
                "W",
            )
        d = _matrix(self.D, "EstimatorParams.D")
        if np.linalg.eigvalsh(d)[0] <= 0.0:
            raise ConfigError(f"must be positive definite, eigenvalues {np.linalg.eigvalsh(d).tolist()}", "D")
        for name, ok in (
            ("m", math.isfinite(self.m) and self.m > 0),
            ("newton_tol", self.newton_tol > 0),
            ("newton_max_iter", self.newton_max_iter >= 1),
            ("max_step_s", self.max_step_s > 0),
            ("on_newton_failure", self.on_newton_failure in ("flag", "raise")),
            ("min_direction_angle_deg", 0 < self.min_direction_angle_deg < 90),
        ):
            if not ok:
                raise ConfigError(f"invalid value {getattr(self, name)!r}", f"EstimatorParams.{name}")
        object.__setattr__(self, "E", e_full)
        object.__setattr__(self, "W", w)
        object.__setattr__(self, "D", d)
        object.__setattr__(self, "m", float(self.m))

    @classmethod
    def paper(cls, **overrides: object) -> EstimatorParams:
        """The paper's experiment: its E (ENU), W, m = 0.5, D = diag(12, 13, 14), Φ(x) = x."""
        return cls(**overrides)  # type: ignore[arg-type]


def paper_initial_attitude(r_true: ArrayLike) -> Array:
    """The paper's initial estimate for a true attitude ``R``: ``R̂0 = Q0ᵀ R`` with ``Q0 = R R̂0ᵀ`` ≈ 127°."""
    return so3.exp(PAPER_Q0_ROTVEC).T @ np.asarray(r_true, dtype=float)


def wahba(params: EstimatorParams, acc: ArrayLike, mag: ArrayLike) -> Array:
    """The attitude minimising the potential U⁰ for one pair of measurements (Wahba's problem, by SVD of
    ``L = E W Uᵀ``): the natural initial estimate for a real log. Body → inertial, (3, 3)."""
    u1, u2 = _unit(acc, "acc"), _unit(mag, "mag")
    c = np.cross(u1, u2)
    u = np.column_stack([u1, u2, c / np.linalg.norm(c)])
    b = params.E @ params.W @ u.T
    left, _, right_t = np.linalg.svd(b)
    d = np.sign(np.linalg.det(left) * np.linalg.det(right_t))
    return left @ np.diag([1.0, 1.0, d]) @ right_t


# --------------------------------------------------------------------------- measurement terms
class _Tables:
    """Constants of one parameter set in the shapes the per-step kernel wants (Python floats)."""

    def __init__(self, p: EstimatorParams) -> None:
        self.m = p.m
        self.D: Mat9 = tuple(p.D.reshape(-1).tolist())  # type: ignore[assignment]
        diagonal = not np.any(p.D - np.diag(np.diag(p.D)))
        self.D_diag: Vec3 | None = tuple(np.diag(p.D).tolist()) if diagonal else None  # type: ignore[assignment]
        self.tol = p.newton_tol
        self.max_iter = p.newton_max_iter
        self.raise_on_failure = p.on_newton_failure == "raise"
        self.max_step = p.max_step_s
        self.phi_prime = p.phi.derivative
        self.phi_const = p.phi.constant_derivative
        self.min_sin = math.sin(math.radians(p.min_direction_angle_deg))
        # per usable-direction mask: M = E W_S (so L = M Uᵀ) and tr(E_Sᵀ E_S W_SS)
        self.W_sel = np.zeros((8, 3, 3))
        self.M = np.zeros((8, 3, 3))
        self.trace_e = np.zeros(8)
        for mask in range(8):
            sel = np.array([bool(mask & b) for b in (_ACC, _MAG, _CROSS)], dtype=float)
            self.W_sel[mask] = p.W * np.outer(sel, sel)
            self.M[mask] = p.E @ self.W_sel[mask]
            self.trace_e[mask] = float(np.trace(p.E.T @ p.E @ self.W_sel[mask]))
        self.M_f: list[Mat9] = [tuple(x.reshape(-1).tolist()) for x in self.M]  # type: ignore[misc]


def _mask_of(acc_ok: bool, mag_ok: bool, cross_ok: bool) -> int:
    return (_ACC if acc_ok else 0) | (_MAG if mag_ok else 0) | (_CROSS if cross_ok else 0)


def _measurement_f(tb: _Tables, acc: Vec3 | None, mag: Vec3 | None) -> tuple[Mat9 | None, float, StepFlag]:
    """``(L, ½ tr(E_SᵀE_S W) + ½ tr(U_SᵀU_S W), flags)`` for one step; L None when no direction is usable.

    With ``L`` and that constant ``k``, ``U⁰ = k − ⟨R̂, L⟩`` (R̂ orthonormal), so U⁰ costs 9 products.
    """
    u1 = _normalised(acc)
    u2 = _normalised(mag)
    flags = StepFlag.NONE
    u3 = None
    if u1 is not None and u2 is not None:
        cx = u1[1] * u2[2] - u1[2] * u2[1]
        cy = u1[2] * u2[0] - u1[0] * u2[2]
        cz = u1[0] * u2[1] - u1[1] * u2[0]
        n = math.sqrt(cx * cx + cy * cy + cz * cz)
        if n >= tb.min_sin:
            u3 = (cx / n, cy / n, cz / n)
        else:  # (nearly) parallel: the magnetometer adds nothing trustworthy
            flags |= StepFlag.DEGENERATE
            u2 = None
    mask = _mask_of(u1 is not None, u2 is not None, u3 is not None)
    if mask == 0:
        return None, 0.0, flags
    zero = (0.0, 0.0, 0.0)
    a = u1 or zero
    b = u2 or zero
    c = u3 or zero
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = tb.M_f[mask]
    a0, a1, a2 = a
    b0, b1, b2 = b
    c0, c1, c2 = c
    # L = M Uᵀ: L[i][j] = Σ_k M[i][k] U[j][k], U's columns being a, b, c
    big_l: Mat9 = (
        m0 * a0 + m1 * b0 + m2 * c0, m0 * a1 + m1 * b1 + m2 * c1, m0 * a2 + m1 * b2 + m2 * c2,
        m3 * a0 + m4 * b0 + m5 * c0, m3 * a1 + m4 * b1 + m5 * c1, m3 * a2 + m4 * b2 + m5 * c2,
        m6 * a0 + m7 * b0 + m8 * c0, m6 * a1 + m7 * b1 + m8 * c1, m6 * a2 + m7 * b2 + m8 * c2,
    )  # fmt: skip
    k = 0.5 * tb.trace_e[mask]
    if tb.phi_const is None:
        u = np.array([a, b, c])  # rows are U's columns; zero rows for unused ones
        k += 0.5 * float(np.sum((u @ u.T) * tb.W_sel[mask]))
    return big_l, k, flags


def _normalised(v: Vec3 | None) -> Vec3 | None:
    if v is None:
        return None
    x, y, z = v
    n = math.sqrt(x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        return None
    return (x / n, y / n, z / n)


def _measurement_batch(
    tb: _Tables, acc: Array, mag: Array
) -> tuple[list[list[float] | None], list[float], NDArray[np.int64]]:
    """:func:`_measurement_f` for N steps at once (vectorised); rows of ``acc``/``mag`` with a NaN are
    not usable. Returns per step ``L`` (9 floats, row-major, or None), the constant ``k``, and flags."""
    n = acc.shape[0]

    def unit(v: Array) -> tuple[Array, NDArray[np.bool_]]:
        norm = np.linalg.norm(v, axis=1)
        ok = np.isfinite(norm) & (norm > 0.0)
        return np.where(ok[:, None], v / np.where(ok, norm, 1.0)[:, None], 0.0), ok

    u1, ok1 = unit(acc)
    u2, ok2 = unit(mag)
    cross = np.cross(u1, u2)
    cn = np.linalg.norm(cross, axis=1)
    both = ok1 & ok2
    degenerate = both & (cn < tb.min_sin)
    ok2 &= ~degenerate
    u2[degenerate] = 0.0
    ok3 = both & ~degenerate
    u3 = np.where(ok3[:, None], cross / np.where(ok3, cn, 1.0)[:, None], 0.0)
    mask = ok1 * _ACC + ok2 * _MAG + ok3 * _CROSS
    cols = np.stack([u1, u2, u3], axis=2)  # cols[n, j, k] = U[n][j][k], columns a, b, c
    big_l = np.einsum("nik,njk->nij", tb.M[mask], cols).reshape(n, 9)
    k = 0.5 * tb.trace_e[mask]
    if tb.phi_const is None:
        gram = np.einsum("nji,njk->nik", cols, cols)
        k = k + 0.5 * np.einsum("nik,nik->n", gram, tb.W_sel[mask])
    rows: list[list[float] | None] = big_l.tolist()
    for i in np.flatnonzero(mask == 0).tolist():
        rows[i] = None
    flags = np.where(degenerate, int(StepFlag.DEGENERATE), 0).astype(np.int64)
    return rows, k.tolist(), flags


# --------------------------------------------------------------------------- the step
def _torque(tb: _Tables, r: Mat9, big_l: Mat9 | list[float] | None, k: float) -> Vec3:
    """``Φ'(U⁰(R̂, U)) S_L(R̂)`` with ``S_L = vex(Lᵀ R̂ − R̂ᵀ L)`` and ``U⁰ = k − ⟨R̂, L⟩``."""
    if big_l is None:
        return (0.0, 0.0, 0.0)
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    l0, l1, l2, l3, l4, l5, l6, l7, l8 = big_l
    # A = Lᵀ R̂ (only the off-diagonal entries are needed): A_ij = Σ_k L_ki R̂_kj; S_L = vex(A − Aᵀ)
    sx = (l2 * r1 + l5 * r4 + l8 * r7) - (l1 * r2 + l4 * r5 + l7 * r8)
    sy = (l0 * r2 + l3 * r5 + l6 * r8) - (l2 * r0 + l5 * r3 + l8 * r6)
    sz = (l1 * r0 + l4 * r3 + l7 * r6) - (l0 * r1 + l3 * r4 + l6 * r7)
    g = tb.phi_const
    if g is None:
        inner = r0 * l0 + r1 * l1 + r2 * l2 + r3 * l3 + r4 * l4 + r5 * l5 + r6 * l6 + r7 * l7 + r8 * l8
        g = tb.phi_prime(k - inner)
    return (g * sx, g * sy, g * sz)


def _newton(tb: _Tables, hh: float, g1: Vec3, c: Vec3) -> tuple[Vec3, int, bool]:
    """Solve ``m ω = exp(φ(ω)^×) c``, ``φ = hh (ω − g1)``, for ω by Newton–Raphson (see module doc).

    Start: one fixed-point pass ``ω = exp(φ(c/m)^×) c / m`` (error O(h²|Ω̂|²|ω|)). Each iteration evaluates
    the residual ``f = m ω − exp(φ^×) c``; it stops when ``‖f‖ / m ≤ newton_tol · √(1 + ‖ω‖²)`` (≈ the
    size of the next Newton update, since ``∂f/∂ω = m I + O(h)``), else takes the update ``J⁻¹ f``.
    Returns ``(ω, Newton updates taken, converged)``.
    """
    m = tb.m
    tol2 = (m * tb.tol) ** 2
    cx, cy, cz = c
    gx, gy, gz = g1
    wx, wy, wz = rotate_f(hh * (cx / m - gx), hh * (cy / m - gy), hh * (cz / m - gz), cx / m, cy / m, cz / m)
    for it in range(tb.max_iter + 1):
        px, py, pz = hh * (wx - gx), hh * (wy - gy), hh * (wz - gz)
        t2 = px * px + py * py + pz * pz
        a, b, cc = rodrigues_coefficients(t2)
        # y = exp(φ^×) c, f = m ω − y
        qx, qy, qz = py * cz - pz * cy, pz * cx - px * cz, px * cy - py * cx
        yx = cx + a * qx + b * (py * qz - pz * qy)
        yy = cy + a * qy + b * (pz * qx - px * qz)
        yz = cz + a * qz + b * (px * qy - py * qx)
        fx, fy, fz = m * wx - yx, m * wy - yy, m * wz - yz
        if fx * fx + fy * fy + fz * fz <= tol2 * (1.0 + wx * wx + wy * wy + wz * wz):
            return (wx, wy, wz), it, True
        if it == tb.max_iter or not math.isfinite(fx + fy + fz):
            break
        # J = m I + hh [(1 − cc θ²) y^× + b (φ yᵀ − (y·φ) I) + cc (y×φ) φᵀ]
        e = hh * (1.0 - cc * t2)
        hb = hh * b
        hc = hh * cc
        sx, sy, sz = hc * (yy * pz - yz * py), hc * (yz * px - yx * pz), hc * (yx * py - yy * px)
        d = m - hb * (yx * px + yy * py + yz * pz)
        j0, j1, j2 = (
            d + hb * px * yx + sx * px,
            -e * yz + hb * px * yy + sx * py,
            e * yy + hb * px * yz + sx * pz,
        )
        j3, j4, j5 = (
            e * yz + hb * py * yx + sy * px,
            d + hb * py * yy + sy * py,
            -e * yx + hb * py * yz + sy * pz,
        )
        j6, j7, j8 = (
            -e * yy + hb * pz * yx + sz * px,
            e * yx + hb * pz * yy + sz * py,
            d + hb * pz * yz + sz * pz,
        )
        # Newton update Δ = J⁻¹ f by Cramer's rule (J ≈ m I: never near-singular for a sane step)
        c0, c1, c2 = j4 * j8 - j5 * j7, j5 * j6 - j3 * j8, j3 * j7 - j4 * j6
        inv = 1.0 / (j0 * c0 + j1 * c1 + j2 * c2)
        wx -= (c0 * fx + (j2 * j7 - j1 * j8) * fy + (j1 * j5 - j2 * j4) * fz) * inv
        wy -= (c1 * fx + (j0 * j8 - j2 * j6) * fy + (j2 * j3 - j0 * j5) * fz) * inv
        wz -= (c2 * fx + (j1 * j6 - j0 * j7) * fy + (j0 * j4 - j1 * j3) * fz) * inv
    return (wx, wy, wz), tb.max_iter, False


def _advance(
    tb: _Tables,
    r: Mat9,
    w: Vec3,
    g0: Vec3,
    tau0: Vec3,
    h: float,
    g1: Vec3,
    big_l: Mat9 | list[float] | None,
    k1: float,
) -> tuple[Mat9, Vec3, Vec3, int, bool]:
    """One step of Proposition 1 from ``(R̂[i], ω[i])`` with ``Ω^m[i] = g0`` and the cached
    ``Φ'(U⁰[i]) S_L[i] = tau0`` to step i+1 with ``Ω^m[i+1] = g1`` and measurement ``(L, k)``.

    Returns ``(R̂[i+1], ω[i+1], Φ'(U⁰[i+1]) S_L[i+1], Newton updates, converged)``.
    """
    m = tb.m
    hh = 0.5 * h
    wx, wy, wz = w
    g0x, g0y, g0z = g0
    t0x, t0y, t0z = tau0
    # ω[i+½] = (m I + h/2 D)⁻¹ { exp(−h/2 Ω̂[i]^×) m ω[i] + h/2 τ[i] }
    vx, vy, vz = rotate_f(hh * (wx - g0x), hh * (wy - g0y), hh * (wz - g0z), m * wx, m * wy, m * wz)
    bx, by, bz = vx + hh * t0x, vy + hh * t0y, vz + hh * t0z
    if tb.D_diag is not None:
        dx, dy, dz = tb.D_diag
        hx, hy, hz = bx / (m + hh * dx), by / (m + hh * dy), bz / (m + hh * dz)
    else:
        d0, d1, d2, d3, d4, d5, d6, d7, d8 = tb.D
        mx = (m + hh * d0, hh * d1, hh * d2, hh * d3, m + hh * d4, hh * d5, hh * d6, hh * d7, m + hh * d8)
        hx, hy, hz = solve3_f(mx, (bx, by, bz))
    # R̂[i+1] = R̂[i] exp(h (Ω^m[i+½] − ω[i+½])^×)
    g1x, g1y, g1z = g1
    step = so3.exp_f(h * (0.5 * (g0x + g1x) - hx), h * (0.5 * (g0y + g1y) - hy), h * (0.5 * (g0z + g1z) - hz))
    r1 = reorthonormalize_f(matmul_f(r, step))
    t1x, t1y, t1z = tau1 = _torque(tb, r1, big_l, k1)
    # m ω[i+1] = exp(−h/2 Ω̂[i+1]^×) { (m I − h/2 D) ω[i+½] + h/2 τ[i+1] }
    if tb.D_diag is not None:
        c = ((m - hh * dx) * hx + hh * t1x, (m - hh * dy) * hy + hh * t1y, (m - hh * dz) * hz + hh * t1z)
    else:
        c = (
            m * hx - hh * (d0 * hx + d1 * hy + d2 * hz) + hh * t1x,
            m * hy - hh * (d3 * hx + d4 * hy + d5 * hz) + hh * t1y,
            m * hz - hh * (d6 * hx + d7 * hy + d8 * hz) + hh * t1z,
        )
    w1, iters, ok = _newton(tb, hh, g1, c)
    return r1, w1, tau1, iters, ok


def _run(
    tb: _Tables,
    state: tuple[Mat9, Vec3, Vec3, Vec3],
    hs: list[float],
    gyrs: list[list[float]],
    big_ls: list[list[float] | None],
    ks: list[float],
    out_r: list[Mat9],
    out_w: list[Vec3],
    out_flags: list[int],
    out_iters: list[int],
) -> tuple[tuple[Mat9, Vec3, Vec3, Vec3], int, int, int]:
    """Step through samples ``i`` (steps ``hs[i]`` s, rates ``gyrs[i]``, measurements ``(big_ls[i], ks[i])``)
    from ``state = (R̂, ω, Ω^m, τ)``, appending each step's R̂, ω, flag bits and Newton updates to the
    ``out_*`` lists. Returns the final state, the sub-steps taken, the Newton updates taken and the most
    in one step.

    The one loop both :meth:`VariationalEstimator.update` and ``update_batch`` run (locals only: at
    ~10 µs a step, attribute and call overhead would otherwise be a third of the cost).
    """
    r, w, g0, tau = state
    max_step = tb.max_step
    substeps = most = updates = 0
    for h, g, big_l, k in zip(hs, gyrs, big_ls, ks, strict=True):
        g1: Vec3 = (g[0], g[1], g[2])
        if h <= max_step:
            r, w, tau, total, ok = _advance(tb, r, w, g0, tau, h, g1, big_l, k)
            flags = 0 if ok else _NEWTON_FAILED
        else:  # sub-steps: gyro interpolated linearly, measurement held
            n_sub = math.ceil(h / max_step)
            a0, a1, a2 = g0
            flags, total = _SUBSTEPPED, 0
            for j in range(1, n_sub + 1):
                f = j / n_sub
                ga = (
                    (a0 + f * (g1[0] - a0), a1 + f * (g1[1] - a1), a2 + f * (g1[2] - a2)) if j < n_sub else g1
                )
                r, w, tau, iters, ok = _advance(tb, r, w, g0, tau, h / n_sub, ga, big_l, k)
                g0 = ga
                total += iters
                flags |= 0 if ok else _NEWTON_FAILED
            substeps += n_sub - 1
        if flags and tb.raise_on_failure and flags & _NEWTON_FAILED:
            raise ConvergenceError(
                f"estimator step {len(out_r)} (h = {h:g} s): Newton–Raphson did not reach "
                f"{tb.tol:g} rad/s in {tb.max_iter} updates (ω = {w})"
            )
        g0 = g1
        out_r.append(r)
        out_w.append(w)
        out_flags.append(flags)
        out_iters.append(total)
        updates += total
        if total > most:
            most = total
    return (r, w, g0, tau), substeps, updates, most


# --------------------------------------------------------------------------- state and outputs
@dataclass(frozen=True)
class EstimatorState:
    """A snapshot of the estimator, enough to resume it exactly (``VariationalEstimator.restore``).

    ``t`` s since the first sample; ``R`` (3, 3) body → inertial; ``omega_err`` (3,) rad/s the rate-estimate
    error ω (``Ω̂ = Ω^m − ω``); ``gyr`` (3,) rad/s the last rate measurement Ω^m[i] used; ``torque`` (3,) the
    cached ``Φ'(U⁰[i]) S_L[i]``; ``started`` whether a first sample has been taken.
    """

    t: float
    R: Array
    omega_err: Array
    gyr: Array
    torque: Array
    started: bool


@dataclass(frozen=True)
class EstimatorStats:
    """Counters since construction (or the last ``reset``)."""

    steps: int = 0
    newton_failures: int = 0
    newton_updates: int = 0
    max_newton_updates: int = 0
    substeps: int = 0
    degenerate: int = 0
    no_direction: int = 0
    gyro_missing: int = 0


@dataclass(frozen=True, slots=True)
class Estimate:
    """The estimator's output for one sample: ``R`` (3, 3) body → inertial (ENU), ``omega`` (3,) rad/s the
    body rate estimate Ω̂, ``omega_err`` (3,) rad/s ω, ``t`` s, ``flags``, Newton ``iterations`` taken."""

    t: float
    R: Array
    omega: Array
    omega_err: Array
    flags: StepFlag
    iterations: int


@dataclass(frozen=True)
class EstimateBatch:
    """Outputs for N steps: ``t`` (N,), ``R`` (N, 3, 3), ``omega`` (N, 3) Ω̂ rad/s, ``omega_err`` (N, 3),
    ``flags`` (N,) :class:`StepFlag` bits (the merger's and the estimator's), ``iterations`` (N,)."""

    t: Array
    R: Array
    omega: Array
    omega_err: Array
    flags: NDArray[np.int64]
    iterations: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def quat(self) -> Array:
        """Attitude as unit quaternions ``[w, x, y, z]`` (N, 4), body → inertial."""
        return so3.matrix_to_quat(self.R)


# --------------------------------------------------------------------------- the estimator
class VariationalEstimator:
    """The paper's estimator, one sample at a time (:meth:`update`) or over merged steps
    (:meth:`update_batch`); both run the same kernel and give identical numbers.

    ``R0`` (3, 3) is the initial attitude estimate (body → inertial; default identity — see :func:`wahba`
    to start from the first measurement, :func:`paper_initial_attitude` for the paper's 127° error);
    ``omega_err0`` (3,) rad/s the initial rate-estimate error ω0.
    """

    def __init__(
        self,
        params: EstimatorParams | None = None,
        R0: ArrayLike | None = None,
        omega_err0: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        self.params = params or EstimatorParams()
        self._tb = _Tables(self.params)
        self.reset(R0, omega_err0)

    def reset(self, R0: ArrayLike | None = None, omega_err0: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        """Start over from ``R0`` (default identity; projected onto SO(3)) and ``omega_err0``."""
        r = np.eye(3) if R0 is None else so3.project(np.asarray(R0, dtype=float).reshape(3, 3))
        self._r: Mat9 = tuple(r.reshape(-1).tolist())  # type: ignore[assignment]
        w = as_vec3(omega_err0)
        if w is None:
            raise ConfigError(f"must be a finite 3-vector, got {omega_err0!r}", "omega_err0")
        self._w: Vec3 = w
        self._g: Vec3 = (0.0, 0.0, 0.0)
        self._tau: Vec3 = (0.0, 0.0, 0.0)
        self._t = 0.0
        self._started = False
        self._flag_steps = self._no_direction = self._substeps = self._newton_updates = self._max_updates = 0
        self._flag_counts = dict.fromkeys(_COUNTED, 0)

    # ----------------------------------------------------------------- snapshot / restore
    @property
    def state(self) -> EstimatorState:
        return EstimatorState(
            self._t,
            np.array(self._r).reshape(3, 3),
            np.array(self._w),
            np.array(self._g),
            np.array(self._tau),
            self._started,
        )

    def restore(self, state: EstimatorState) -> None:
        """Continue from a snapshot taken with :attr:`state` (counters are kept)."""
        self._t = float(state.t)
        self._r = tuple(np.asarray(state.R, dtype=float).reshape(-1).tolist())  # type: ignore[assignment]
        self._w = tuple(np.asarray(state.omega_err, dtype=float).tolist())  # type: ignore[assignment]
        self._g = tuple(np.asarray(state.gyr, dtype=float).tolist())  # type: ignore[assignment]
        self._tau = tuple(np.asarray(state.torque, dtype=float).tolist())  # type: ignore[assignment]
        self._started = bool(state.started)

    @property
    def stats(self) -> EstimatorStats:
        fc = self._flag_counts
        return EstimatorStats(
            steps=self._flag_steps,
            newton_failures=fc[StepFlag.NEWTON_FAILED],
            newton_updates=self._newton_updates,
            max_newton_updates=self._max_updates,
            substeps=self._substeps,
            degenerate=fc[StepFlag.DEGENERATE],
            no_direction=self._no_direction,
            gyro_missing=fc[StepFlag.GYR_STALE],
        )

    @property
    def R(self) -> Array:
        """Current attitude estimate (3, 3), body → inertial."""
        return np.array(self._r).reshape(3, 3)

    @property
    def omega(self) -> Array:
        """Current body rate estimate Ω̂ = Ω^m − ω (3,), rad/s."""
        return np.subtract(self._g, self._w)

    # ----------------------------------------------------------------- stepping
    def update(
        self,
        dt: float,
        gyr: ArrayLike | None,
        acc: ArrayLike | None = None,
        mag: ArrayLike | None = None,
    ) -> Estimate:
        """Take one sample: ``dt`` s since the previous one (ignored on the first call, which only
        initialises), ``gyr`` (3,) rad/s, ``acc`` (3,) m/s² (any unit: only its direction is used), ``mag``
        (3,) (direction only), all body frame. None or non-finite means 'not usable' (see the module doc).
        Returns the estimate at this sample."""
        tb = self._tb
        g = as_vec3(gyr)
        flags = StepFlag.NONE
        if g is None:
            g = (0.0, 0.0, 0.0)
            flags |= StepFlag.GYR_STALE
        big_l, k, mflags = _measurement_f(tb, as_vec3(acc), as_vec3(mag))
        flags |= mflags
        if self._started:
            if not (math.isfinite(dt) and dt > 0.0):
                raise ValueError(f"update: dt must be a positive number of seconds, got {dt!r}")
            f_out: list[int] = []
            it_out: list[int] = []
            self._advance_all([dt], [list(g)], [big_l], [k], [], [], f_out, it_out)  # type: ignore[list-item]
            self._t += dt
            flags |= f_out[0]
            iters = it_out[0]
        else:
            iters = self._start(g, big_l, k)
        self._tally(int(flags), big_l is None)
        return Estimate(
            self._t,
            np.array(self._r).reshape(3, 3),
            np.subtract(g, self._w),
            np.array(self._w),
            flags,
            iters,
        )

    def update_batch(self, steps: MergedSteps) -> EstimateBatch:
        """Run over merged steps (``steps.t`` strictly increasing), continuing from the current state.

        Times are on the caller's clock: an estimator that has not started adopts ``steps.t[0]`` as its
        time; one that has steps from its current time (``state.t``) to ``steps.t[0]`` first.

        The merger's flags are carried into the output; a step whose sensor is flagged stale is fed to the
        filter as 'not usable'. Same numbers as calling :meth:`update` step by step (to rounding: the
        measurement terms are computed vectorised here).
        """
        tb = self._tb
        n = len(steps)
        t = steps.t
        if n and not np.all(np.diff(t) > 0):
            k = int(np.flatnonzero(~(np.diff(t) > 0))[0])
            raise ValueError(f"update_batch: step times must increase strictly (step {k + 1}: {t[k + 1]!r})")
        gyr_ok = steps.valid(SensorKind.GYR) & np.all(np.isfinite(steps.gyr), axis=1)
        acc = np.where(steps.valid(SensorKind.ACC)[:, None], steps.acc, np.nan)
        mag = np.where(steps.valid(SensorKind.MAG)[:, None], steps.mag, np.nan)
        big_ls, ks, mflags = _measurement_batch(tb, acc, mag)
        gyr = np.where(gyr_ok[:, None], steps.gyr, 0.0)
        flags = steps.flags | mflags | np.where(gyr_ok, 0, int(StepFlag.GYR_STALE))
        out_r: list[Mat9] = []
        out_w: list[Vec3] = []
        step_flags: list[int] = []
        iters: list[int] = []
        gyrs = gyr.tolist()
        first = 0
        if n and not self._started:
            self._t = float(t[0])
            self._start(tuple(gyrs[0]), big_ls[0], ks[0])  # type: ignore[arg-type]
            out_r.append(self._r)
            out_w.append(self._w)
            step_flags.append(0)
            iters.append(0)
            first = 1
        hs = np.diff(t, prepend=self._t)[first:].tolist()
        if hs and not hs[0] > 0:
            raise ValueError(
                f"update_batch: first step time {t[0]!r} is not after the estimator's {self._t!r}"
            )
        self._t = float(t[-1]) if n else self._t
        self._advance_all(hs, gyrs[first:], big_ls[first:], ks[first:], out_r, out_w, step_flags, iters)
        flags |= np.asarray(step_flags, dtype=np.int64).reshape(n)
        self._tally(flags, sum(b is None for b in big_ls))
        w_arr = np.asarray(out_w, dtype=float).reshape(n, 3)
        return EstimateBatch(
            t.copy(),
            np.asarray(out_r, dtype=float).reshape(n, 3, 3),
            gyr - w_arr,
            w_arr,
            flags,
            np.asarray(iters, dtype=np.int64).reshape(n),
        )

    def _start(self, g: Vec3, big_l: Mat9 | list[float] | None, k: float) -> int:
        """Take the first sample: it sets Ω^m[0] and the cached torque at R̂0; no step."""
        self._started = True
        self._g = g
        self._tau = _torque(self._tb, self._r, big_l, k)
        return 0

    def _advance_all(
        self,
        hs: list[float],
        gyrs: list[list[float]],
        big_ls: list[list[float] | None],
        ks: list[float],
        *outs: list,  # type: ignore[type-arg]
    ) -> None:
        state = (self._r, self._w, self._g, self._tau)
        state, substeps, updates, most = _run(self._tb, state, hs, gyrs, big_ls, ks, *outs)
        self._r, self._w, self._g, self._tau = state
        self._substeps += substeps
        self._newton_updates += updates
        self._max_updates = max(self._max_updates, most)

    def _tally(self, flags: NDArray[np.int64] | int, no_direction: int) -> None:
        """Count steps and the flag bits that feed :class:`EstimatorStats` (one step's int, or an array)."""
        if isinstance(flags, int):
            self._flag_steps += 1
            if flags:
                for bit in _COUNTED:
                    self._flag_counts[bit] += bool(flags & bit)
        else:
            self._flag_steps += int(flags.shape[0])
            for bit in _COUNTED:
                self._flag_counts[bit] += int(np.count_nonzero(flags & int(bit)))
        self._no_direction += int(no_direction)


_NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)
_SUBSTEPPED = int(StepFlag.SUBSTEPPED)
_COUNTED = (StepFlag.NEWTON_FAILED, StepFlag.DEGENERATE, StepFlag.GYR_STALE)


# --------------------------------------------------------------------------- pre-filter + estimator
PAPER_PREFILTER: dict[SensorKind, float | None] = {k: PAPER_CUTOFF_RAD_S for k in KINDS}
"""The paper's pre-filter: every measured quantity through the 1 rad/s first-order Butterworth."""


@dataclass(frozen=True)
class FilterConfig:
    """The estimator as it runs on a phone's merged steps: what happens to the measurements first.

    ``prefilter_rad_s``: pre-filter cut-off per sensor (rad/s), None for none; ``prefilter_frame``
    ``"body"`` (the paper) or ``"strapdown"`` (see :class:`hil.estimation.prefilter.SignalPrefilter`).
    ``gyro_bias`` (3,) rad/s: subtracted from every gyro sample first (e.g. measured over a still window).
    ``magnetometer``: ``"full"`` uses the field direction as measured (the paper; E's e2 is the full field
    direction); ``"horizontal"`` uses its component perpendicular to the measured gravity direction, so that
    the magnetometer informs heading only (E's e2 must then be horizontal, e.g. magnetic north).
    ``init``: initial attitude — ``"measured"`` (Wahba's solution from the first step with both directions),
    ``"identity"``, or a (3, 3) body → inertial matrix; ``omega_err0`` (3,) rad/s the initial ω.
    ``mag_gate``: reject disturbed magnetometer samples (:class:`hil.estimation.prefilter.MagneticGate`),
    or None.
    """

    params: EstimatorParams = field(default_factory=EstimatorParams)
    prefilter_rad_s: dict[SensorKind, float | None] = field(default_factory=lambda: dict(PAPER_PREFILTER))
    prefilter_frame: Literal["body", "strapdown"] = "body"
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    magnetometer: Literal["full", "horizontal"] = "full"
    init: Literal["measured", "identity"] | ArrayLike = "measured"
    omega_err0: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_gate: GateSettings | None = None

    def __post_init__(self) -> None:
        if self.magnetometer not in ("full", "horizontal"):
            raise ConfigError(
                f"must be 'full' or 'horizontal', got {self.magnetometer!r}", "FilterConfig.magnetometer"
            )
        if self.magnetometer == "horizontal" and abs(float(self.params.E[2, 1])) > 1e-9:
            raise ConfigError(
                "a horizontal magnetometer needs a horizontal e2 (E[2, 1] = 0)", "FilterConfig.params.E"
            )
        if as_vec3(self.gyro_bias) is None:
            raise ConfigError(f"must be a finite 3-vector, got {self.gyro_bias!r}", "FilterConfig.gyro_bias")
        if isinstance(self.init, str) and self.init not in ("measured", "identity"):
            raise ConfigError(f"must be 'measured', 'identity' or a 3x3 matrix, got {self.init!r}", "init")

    @classmethod
    def paper(cls, E: ArrayLike | None = None, **overrides: object) -> FilterConfig:
        """Exactly the paper: its W, m, D, Φ(x) = x, the 1 rad/s body-frame pre-filter on all three
        signals, the full field direction; ``E`` defaults to the paper's (its site's field)."""
        params = EstimatorParams() if E is None else EstimatorParams(E=np.asarray(E, dtype=float))
        return cls(params=params, **overrides)  # type: ignore[arg-type]

    @classmethod
    def tuned(cls, declination_deg: float = 0.0, **overrides: object) -> FilterConfig:
        """The paper's estimator with the gains and measurement handling tuned on real phone/IMU logs
        (see docs/estimator.md, "Tuning"): :data:`TUNED`; E is magnetic north (or true north given the
        declination) with a horizontal magnetometer, so only the field's direction in the horizontal
        plane matters and no inclination is needed."""
        from hil.estimation.inertial import directions_from_dip

        params = EstimatorParams(E=directions_from_dip(0.0, declination_deg), W=np.diag(TUNED["W_diag"]),
                                 m=TUNED["m"], D=np.diag(TUNED["D_diag"]))  # fmt: skip
        cut = {SensorKind.ACC: TUNED["acc_cutoff"], SensorKind.MAG: TUNED["mag_cutoff"], SensorKind.GYR: None}
        base = {
            "params": params,
            "prefilter_rad_s": cut,
            "prefilter_frame": "strapdown",
            "magnetometer": "horizontal",
            "mag_gate": TUNED["mag_gate"],
        }
        return cls(**{**base, **overrides})  # type: ignore[arg-type]


TUNED: dict = {
    "W_diag": (6.0, 1.0, 0.25),
    "m": 0.1,
    "D_diag": (6.0, 6.5, 7.0),
    "acc_cutoff": 0.15,
    "mag_cutoff": None,
    "mag_gate": GateSettings(norm_tol=0.2, dip_tol_deg=15.0),
}
"""Tuned settings: a two-stage grid search (``python -m bench.bench_estimator --tune``) minimising the
mean total RMSE over six real trials (three tyrex smartphone, three BROAD), then the magnetometer gate's
tolerances chosen on the same six; see docs/estimator.md."""


class AttitudeFilter:
    """Gyro bias removal, pre-filter, magnetometer handling, then the estimator, over merged steps:
    :meth:`step` live (one :class:`MergedStep`), :meth:`run` in batch (:class:`MergedSteps`); both give
    the same numbers (to rounding).

    With ``init="measured"`` the estimator (re)starts at the first step where both directions are usable,
    from Wahba's solution for that step's (pre-filtered) measurement; steps before it run from identity.
    """

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = config or FilterConfig()
        self.prefilter = SignalPrefilter(self.config.prefilter_rad_s, self.config.prefilter_frame)
        init = self.config.init
        r0 = None if isinstance(init, str) else init
        self._awaiting_measurement = isinstance(init, str) and init == "measured"
        self.estimator = VariationalEstimator(self.config.params, r0, self.config.omega_err0)
        self._bias = self.config.gyro_bias
        gate = self.config.mag_gate
        self.gate = None if gate is None else MagneticGate(*astuple(gate))

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Subtract ``bias`` (3,) rad/s from every later gyro sample: a bias measured while running (the
        host's still window) — the estimator's attitude would otherwise carry a steady offset from it."""
        b = as_vec3(tuple(np.asarray(bias, dtype=float).tolist()))
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias!r}", "AttitudeFilter.set_gyro_bias")
        self._bias = b

    def step(self, s: MergedStep) -> Estimate:
        """One merged step (live path)."""
        g = s.gyr
        if g is not None:
            b = self._bias
            g = (g[0] - b[0], g[1] - b[1], g[2] - b[2])
        g, acc, mag = self.prefilter.step(s.h, g, s.acc, s.mag)
        gated = StepFlag.NONE
        if self.gate is not None and mag is not None:
            mag = self.gate.step(s.h, acc, mag)
            gated = StepFlag.MAG_DISTURBED if mag is None else gated
        if self.config.magnetometer == "horizontal":
            mag = _horizontal_f(acc, mag)
        if self._awaiting_measurement and _both_usable(acc, mag, self.estimator.params):
            self._awaiting_measurement = False
            self.estimator.reset(wahba(self.config.params, acc, mag), self.config.omega_err0)  # type: ignore[arg-type]
        out = self.estimator.update(s.h, g, acc, mag)
        return Estimate(s.t, out.R, out.omega, out.omega_err, out.flags | s.flags | gated, out.iterations)

    def run(
        self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None, chunk: int = 50_000
    ) -> EstimateBatch:
        """All merged steps (batch path). ``progress(done, total)`` is called every ``chunk`` steps."""
        biased = replace(steps, gyr=steps.gyr - np.asarray(self._bias))
        f = self.prefilter.run(biased)
        mag, flags = f.mag, f.flags
        if self.gate is not None:
            mag = self.gate.run(steps.h, f.acc, f.mag)
            flags = flags | np.where(
                np.isnan(mag[:, 0]) & ~np.isnan(f.mag[:, 0]), int(StepFlag.MAG_DISTURBED), 0
            )
        mag = _horizontal_rows(f.acc, mag) if self.config.magnetometer == "horizontal" else mag
        filtered = replace(f, mag=mag, flags=flags)
        start = 0
        if self._awaiting_measurement:
            both = _both_usable_rows(filtered.acc, filtered.mag, self.estimator.params)
            start = int(np.argmax(both)) if both.any() else len(steps)
        parts = []
        bounds = sorted({0, start, len(steps), *range(chunk, len(steps), chunk)})
        for i, j in zip(bounds[:-1], bounds[1:], strict=True):
            if i == start and self._awaiting_measurement:
                self._awaiting_measurement = False
                r0 = wahba(self.config.params, filtered.acc[i], filtered.mag[i])
                self.estimator.reset(r0, self.config.omega_err0)
            parts.append(self.estimator.update_batch(filtered.rows(i, j)))
            if progress is not None:
                progress(j, len(steps))
        if not parts:
            return self.estimator.update_batch(filtered)
        return _concat(parts)


def _horizontal_f(acc: Vec3 | None, mag: Vec3 | None) -> Vec3 | None:
    """The part of ``mag`` perpendicular to ``acc`` (None if either is missing)."""
    if acc is None or mag is None:
        return None
    n2 = acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]
    if not n2 > 0.0:
        return None
    k = (mag[0] * acc[0] + mag[1] * acc[1] + mag[2] * acc[2]) / n2
    return (mag[0] - k * acc[0], mag[1] - k * acc[1], mag[2] - k * acc[2])


def _horizontal_rows(acc: Array, mag: Array) -> Array:
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.sum(mag * acc, axis=1) / np.sum(acc * acc, axis=1)
    return mag - k[:, None] * acc


def _both_usable(acc: Vec3 | None, mag: Vec3 | None, p: EstimatorParams) -> bool:
    if acc is None or mag is None:
        return False
    return bool(_both_usable_rows(np.array([acc]), np.array([mag]), p)[0])


def _both_usable_rows(acc: Array, mag: Array, p: EstimatorParams) -> NDArray[np.bool_]:
    """Rows where both directions are finite, non-zero and not within the degeneracy angle."""
    na, nm = np.linalg.norm(acc, axis=1), np.linalg.norm(mag, axis=1)
    ok = np.isfinite(na) & np.isfinite(nm) & (na > 0) & (nm > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sin = np.linalg.norm(np.cross(acc, mag), axis=1) / (na * nm)
    return ok & (sin >= math.sin(math.radians(p.min_direction_angle_deg)))


def _concat(parts: list[EstimateBatch]) -> EstimateBatch:
    fields = ("t", "R", "omega", "omega_err", "flags", "iterations")
    return EstimateBatch(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))

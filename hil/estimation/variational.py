"""The step of the paper's second-order discrete variational attitude estimator (Viswanathan, Sanyal &
Izadi, arXiv 1509.03677, Proposition 1; Izadi & Sanyal, Automatica 2014) as compiled kernels: the
measurement terms, the potential's torque, the implicit step's Newton solve, one step with its sub-steps,
and the loops :class:`hil.estimation.estimator.VariationalEstimator` calls (one compiled call per sample,
or one per batch). Pure math, no I/O; :mod:`hil.estimation.reference` is the numpy reference the tests
compare every kernel with.

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
flagged :attr:`StepFlag.NEWTON_FAILED` and counted, or raised as :class:`ConvergenceError` by the caller
(``on_newton_failure``). At phone rates one update suffices (quadratic convergence from an O(h²) start).

Missing measurements: a direction that is not usable (NaN input, a stale sensor) is left out of the
potential: ``L = E_S W_SS U_Sᵀ`` over the usable set S ⊆ {acc, mag, acc×mag} (the cross-product column
needs both, and is dropped when they are within ``min_direction_angle_deg`` of parallel). With no usable
direction the potential term vanishes and the filter propagates the gyro. A gyroscope that is not usable
is read as a zero rate measurement (the filter then runs on the vector measurements alone, ``Ω̂ = −ω``).
A rate reading beyond :data:`GYRO_LIMIT` on any axis is not usable either: no rate sensor reads it, and
one of ~1e200 rad/s (finite, so once taken) had overflowed the step into NaN for every later estimate.

Long steps: the scheme's discrete dissipation factor ``(m − h/2 d)/(m + h/2 d)`` turns negative (a
ringing, though bounded, rate error) once ``h > 2m/d``; steps longer than ``max_step_s`` are therefore
split into equal sub-steps with the gyro interpolated linearly and the new measurement held
(:attr:`StepFlag.SUBSTEPPED`), at most :data:`MAX_SUBSTEPS` of them: a longer step is refused as a step
that is not a positive number is (:data:`BAD_STEP`, nothing changed) — a far timestamp had been split into
sub-steps at ~0.13 µs each: a step of 1e8 s took ~4 min, one of 1e10 s hours.

R̂ stays a rotation: each step multiplies by an exact rotation (Rodrigues) and applies one Newton–Schulz
polar correction, which keeps ``‖R̂ᵀR̂ − I‖`` at rounding level however many steps are taken.

Arrays the kernels take (float64 unless said; slots are the ``P_*``, ``S_*``, ``C_*`` constants below;
matrices row-major; a later slot is only ever appended, so a new state — e.g. a gyro bias — extends these):

- parameters ``ep`` (:data:`P_SIZE`), built once by :func:`pack_params`: m, Newton tolerance and cap, the
  failure policy, ``max_step_s``, sin of ``min_direction_angle_deg``, Φ' (kind and argument), D (with a
  diagonal flag), E, W, and per usable-direction mask (bits acc 1, mag 2, acc×mag 4) ``M = E W_S`` (so
  ``L = M Uᵀ``) and ``tr(E_SᵀE_S W_SS)``;
- state ``es`` (:data:`S_SIZE`): R̂, Ω̂ (an output: ``Ω^m − ω`` after the step), ω, Ω^m[i], the cached
  ``Φ'(U⁰[i]) S_L[i]``, the time ``t`` (s), started, then the counters (:data:`C_SIZE` whole numbers
  at ``S_COUNTS + C_*``: the :class:`~hil.estimation.estimator.EstimatorStats` fields). R̂, Ω̂ and ω come
  first and contiguous, so the estimate is one copy of ``es[:15]``.

Two arrays per call, not more: numba's dispatcher costs ~0.1 µs per array argument, and a live step's
whole budget is a few µs.

A step's result is one int: its :class:`StepFlag` bits ``| newton_updates << ITER_SHIFT``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.params import EstimatorParams
from hil.estimation.slots import (
    ACC_STALE,
    DEGENERATE,
    GYR_STALE,
    GYRO_LIMIT,
    MAG_STALE,
    MAX_SUBSTEPS,
    NEWTON_FAILED,
    SUBSTEPPED,
    pack,
)
from hil.jit import jitable, kernel
from hil.so3.floats import exp_f, matmul_f, reorthonormalize_f, rodrigues_coefficients, rotate_f

Array = NDArray[np.float64]

# --------------------------------------------------------------------------- layouts
P_M = 0  # m, the estimator's 'inertia'
P_TOL = 1  # newton_tol (rad/s)
P_MAX_ITER = 2  # newton_max_iter
P_RAISE = 3  # 1: a failed Newton solve stops a batch (on_newton_failure = "raise")
P_MAX_STEP = 4  # max_step_s (s)
P_MIN_SIN = 5  # sin(min_direction_angle_deg)
P_PHI_KIND = 6  # PHI_CONSTANT or PHI_LOG
P_PHI_ARG = 7  # the constant Φ', or the log potential's scale s
P_D_DIAG = 8  # 1: D is diagonal
P_D = 9  # D (9)
P_E = 18  # E (9)
P_W = 27  # W (9)
P_MTAB = 36  # M = E W_S per mask (8 × 9)
P_TRACE = 108  # tr(E_Sᵀ E_S W_SS) per mask (8)
P_BIAS_GAIN = 116  # diagonal of P⁻¹ (3): the bias estimate's gain, rad/s per unit torque per s (0: none)
P_BIAS_MAX = 119  # bound on each component of the bias estimate (rad/s)
P_GYRO_DELAY = 120  # s the gyroscope's readings lag the motion (0: the paper's midpoint rule)
P_BIAS_VERTICAL = 121  # share of the torque along the measured vertical the bias law takes (1: all)
P_SIZE = 122

PHI_CONSTANT = 0  # Φ' constant (Φ linear: the paper's Φ(x) = x)
PHI_LOG = 1  # Φ(x) = s ln(1 + x/s): Φ' = 1 / (1 + x/s)

S_R = 0  # R̂ (9), body → inertial
S_RATE = 9  # Ω̂ = Ω^m − ω (3) rad/s, the rate estimate (an output)
S_OMEGA = 12  # ω (3) rad/s, the rate-estimate error
S_GYR = 15  # Ω^m[i] (3) rad/s, the last rate measurement used (0 when the gyro was not usable)
S_TORQUE = 18  # Φ'(U⁰[i]) S_L[i] (3)
S_T = 21  # time (s)
S_STARTED = 22  # 1 once the first sample is taken
S_COUNTS = 23  # the counters (C_SIZE), at S_COUNTS + C_*
S_BIAS = S_COUNTS + 8  # b̂ (3) rad/s, the gyro bias estimate (constant when P⁻¹ = 0)
S_BIAS_TRUST = S_BIAS + 3  # this step's factor on P⁻¹, in [0, 1] (an input: 1 unless a caller lowers it)
S_MAG_WEIGHT = S_BIAS_TRUST + 1  # this step's weight on the field direction, in [0, 1] (an input, like it)

C_STEPS = 0
C_NEWTON_FAILURES = 1
C_NEWTON_UPDATES = 2
C_MAX_NEWTON_UPDATES = 3
C_SUBSTEPS = 4
C_DEGENERATE = 5
C_NO_DIRECTION = 6
C_GYRO_MISSING = 7
C_SIZE = 8
S_SIZE = S_MAG_WEIGHT + 1

ITER_SHIFT = 16
FLAG_BITS = (1 << ITER_SHIFT) - 1
BAD_STEP = -1
"""What :func:`update` returns, having changed nothing, for a step ``dt`` that is not a positive number, or
longer than :data:`MAX_SUBSTEPS` sub-steps of ``max_step_s``."""

_ACC, _MAG, _CROSS = 1, 2, 4  # bits of the usable-direction mask
_ZERO9 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def pack_params(p: EstimatorParams) -> Array:
    """The parameter array ``ep`` (:data:`P_SIZE`) of ``p`` (see the module docstring for its layout).

    Besides ``p``'s numbers it holds what every step would otherwise recompute: the sine of the
    direction-angle limit, whether D is diagonal (its inverse is then three divisions), and per
    usable-direction mask ``M = E W_S`` and ``tr(E_SᵀE_S W_SS)``, so that a step with a stale sensor costs
    no more than one with all three directions."""
    phi_arg: float | None = p.phi.constant_derivative
    phi_kind = PHI_CONSTANT
    if phi_arg is None:  # EstimatorParams checked that Φ has a compiled form: the log potential's scale
        phi_kind, phi_arg = PHI_LOG, p.phi.log_scale
    assert phi_arg is not None
    slots: dict[int, float | ArrayLike] = {
        P_M: p.m,
        P_TOL: p.newton_tol,
        P_MAX_ITER: p.newton_max_iter,
        P_RAISE: 1.0 if p.on_newton_failure == "raise" else 0.0,
        P_MAX_STEP: p.max_step_s,
        P_MIN_SIN: math.sin(math.radians(p.min_direction_angle_deg)),
        P_PHI_KIND: phi_kind,
        P_PHI_ARG: phi_arg,
        P_D_DIAG: 0.0 if np.any(p.D - np.diag(np.diag(p.D))) else 1.0,
        P_D: p.D,
        P_E: p.E,
        P_W: p.W,
        P_BIAS_GAIN: p.bias_gain,
        P_BIAS_MAX: p.bias_max,
        P_GYRO_DELAY: p.gyro_delay_s,
        P_BIAS_VERTICAL: p.bias_vertical,
    }
    for mask in range(8):
        sel = np.array([bool(mask & b) for b in (_ACC, _MAG, _CROSS)], dtype=float)
        w_sel = p.W * np.outer(sel, sel)
        slots[P_MTAB + 9 * mask] = p.E @ w_sel
        slots[P_TRACE + mask] = float(np.trace(p.E.T @ p.E @ w_sel))
    return pack(P_SIZE, slots)


# --------------------------------------------------------------------------- measurement terms
@kernel
def measurement(ep, ax, ay, az, mx, my, mz, wm):  # type: ignore[no-untyped-def]
    """``(mask, L, k, flags)`` for one step's accelerometer and magnetometer readings (any units; NaN or
    zero means not usable), the field direction taken with weight ``wm`` (its column of U scaled: for a
    diagonal W, W's field weight times ``wm``): the usable-direction mask (0: none), ``L = E W_S U_Sᵀ``
    (9, row-major),
    ``k = ½ tr(E_SᵀE_S W) + ½ tr(U_SᵀU_S W)`` (the second term only for a non-constant Φ') and the
    :attr:`StepFlag.DEGENERATE` bit. With ``L`` and ``k``, ``U⁰ = k − ⟨R̂, L⟩`` (R̂ orthonormal)."""
    flags = 0
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    acc_ok = na > 0.0 and math.isfinite(na)
    mag_ok = nm > 0.0 and math.isfinite(nm)
    a0 = a1 = a2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
    if acc_ok:
        a0, a1, a2 = ax / na, ay / na, az / na
    if mag_ok:
        b0, b1, b2 = mx / nm, my / nm, mz / nm
    cross_ok = False
    if acc_ok and mag_ok:
        cx = a1 * b2 - a2 * b1
        cy = a2 * b0 - a0 * b2
        cz = a0 * b1 - a1 * b0
        n = math.sqrt(cx * cx + cy * cy + cz * cz)
        if n >= ep[P_MIN_SIN]:
            c0, c1, c2 = cx / n, cy / n, cz / n
            cross_ok = True
        else:  # (nearly) parallel: the magnetometer adds nothing trustworthy
            flags |= DEGENERATE
            mag_ok = False
            b0 = b1 = b2 = 0.0
    b0, b1, b2 = wm * b0, wm * b1, wm * b2
    mask = (_ACC if acc_ok else 0) | (_MAG if mag_ok else 0) | (_CROSS if cross_ok else 0)
    if mask == 0:
        return 0, _ZERO9, 0.0, flags
    o = P_MTAB + 9 * mask
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = (
        ep[o],
        ep[o + 1],
        ep[o + 2],
        ep[o + 3],
        ep[o + 4],
        ep[o + 5],
        ep[o + 6],
        ep[o + 7],
        ep[o + 8],
    )
    # L = M Uᵀ: L[i][j] = Σ_k M[i][k] U[j][k], U's columns being a, b, c
    big_l = (
        m0 * a0 + m1 * b0 + m2 * c0, m0 * a1 + m1 * b1 + m2 * c1, m0 * a2 + m1 * b2 + m2 * c2,
        m3 * a0 + m4 * b0 + m5 * c0, m3 * a1 + m4 * b1 + m5 * c1, m3 * a2 + m4 * b2 + m5 * c2,
        m6 * a0 + m7 * b0 + m8 * c0, m6 * a1 + m7 * b1 + m8 * c1, m6 * a2 + m7 * b2 + m8 * c2,
    )  # fmt: skip
    k = 0.5 * ep[P_TRACE + mask]
    if ep[P_PHI_KIND] != PHI_CONSTANT:  # + ½ Σ_ij (u_i·u_j) W_ij, unused columns being zero
        w = P_W
        aa, bb, cc = a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2, c0 * c0 + c1 * c1 + c2 * c2
        ab, ac, bc = a0 * b0 + a1 * b1 + a2 * b2, a0 * c0 + a1 * c1 + a2 * c2, b0 * c0 + b1 * c1 + b2 * c2
        k += 0.5 * (
            aa * ep[w]
            + bb * ep[w + 4]
            + cc * ep[w + 8]
            + ab * (ep[w + 1] + ep[w + 3])
            + ac * (ep[w + 2] + ep[w + 6])
            + bc * (ep[w + 5] + ep[w + 7])
        )
    return mask, big_l, k, flags


# --------------------------------------------------------------------------- the step
@kernel
def torque(ep, r, big_l, mask, k):  # type: ignore[no-untyped-def]
    """``Φ'(U⁰(R̂, U)) S_L(R̂)`` with ``S_L = vex(Lᵀ R̂ − R̂ᵀ L)`` and ``U⁰ = k − ⟨R̂, L⟩``; zero for no
    usable direction (``mask`` 0). ``r`` and ``big_l`` are row-major 9-tuples."""
    if mask == 0:
        return 0.0, 0.0, 0.0
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    l0, l1, l2, l3, l4, l5, l6, l7, l8 = big_l
    # A = Lᵀ R̂ (only the off-diagonal entries are needed): A_ij = Σ_k L_ki R̂_kj; S_L = vex(A − Aᵀ)
    sx = (l2 * r1 + l5 * r4 + l8 * r7) - (l1 * r2 + l4 * r5 + l7 * r8)
    sy = (l0 * r2 + l3 * r5 + l6 * r8) - (l2 * r0 + l5 * r3 + l8 * r6)
    sz = (l1 * r0 + l4 * r3 + l7 * r6) - (l0 * r1 + l3 * r4 + l6 * r7)
    if ep[P_PHI_KIND] == PHI_CONSTANT:
        g = ep[P_PHI_ARG]
    else:
        inner = r0 * l0 + r1 * l1 + r2 * l2 + r3 * l3 + r4 * l4 + r5 * l5 + r6 * l6 + r7 * l7 + r8 * l8
        g = 1.0 / (1.0 + (k - inner) / ep[P_PHI_ARG])
    return g * sx, g * sy, g * sz


@kernel
def newton(ep, hh, g1, c):  # type: ignore[no-untyped-def]
    """Solve ``m ω = exp(φ(ω)^×) c``, ``φ = hh (ω − g1)``, for ω by Newton–Raphson (see module doc).

    Start: one fixed-point pass ``ω = exp(φ(c/m)^×) c / m`` (error O(h²|Ω̂|²|ω|)). Each iteration evaluates
    the residual ``f = m ω − exp(φ^×) c``; it stops when ``‖f‖ / m ≤ newton_tol · √(1 + ‖ω‖²)`` (≈ the
    size of the next Newton update, since ``∂f/∂ω = m I + O(h)``), else takes the update ``J⁻¹ f``.
    Returns ``(ω, Newton updates taken, converged)``.
    """
    m = ep[P_M]
    max_iter = int(ep[P_MAX_ITER])
    tol2 = (m * ep[P_TOL]) ** 2
    cx, cy, cz = c
    gx, gy, gz = g1
    wx, wy, wz = rotate_f(hh * (cx / m - gx), hh * (cy / m - gy), hh * (cz / m - gz), cx / m, cy / m, cz / m)
    for it in range(max_iter + 1):
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
        if it == max_iter or not math.isfinite(fx + fy + fz):
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
    return (wx, wy, wz), max_iter, False


@kernel
def bias_half_step(ep, b, hh, tau, bl):  # type: ignore[no-untyped-def]
    """``b̂ + hh P⁻¹ τ'``, each component kept within ``±bias_max`` (a projection onto a box: it never
    moves the estimate away from a true bias inside it). ``bl = (γ, u)``: ``τ' = γ τ + (ν − γ)(τ·u) u``
    with ``u`` the measured vertical (unit; zero when there is none), ``γ`` the step's trust in the torque
    (1 unless a caller lowers it) and ``ν`` = ``bias_vertical``, the weight of the torque's vertical
    (heading) part. ``γ = ν = 1`` is the variational law."""
    lim = ep[P_BIAS_MAX]
    g = P_BIAS_GAIN
    trust, ux, uy, uz = bl
    c = (ep[P_BIAS_VERTICAL] - trust) * (tau[0] * ux + tau[1] * uy + tau[2] * uz)
    return (
        min(lim, max(-lim, b[0] + hh * ep[g] * (trust * tau[0] + c * ux))),
        min(lim, max(-lim, b[1] + hh * ep[g + 1] * (trust * tau[1] + c * uy))),
        min(lim, max(-lim, b[2] + hh * ep[g + 2] * (trust * tau[2] + c * uz))),
    )


@kernel
def advance(ep, r, w, b, g0, tau0, h, g1, big_l, mask, k, bl):  # type: ignore[no-untyped-def]
    """One step of Proposition 1, extended with the gyro bias estimate b̂ (docs/estimator.md, "Gyro
    bias"), from ``(R̂[i], ω[i], b̂[i])`` with ``Ω^m[i] = g0`` and the cached ``Φ'(U⁰[i]) S_L[i] = tau0``
    to step i+1 with ``Ω^m[i+1] = g1`` and measurement ``(mask, L, k)``::

        b̂[i+½] = b̂[i] + h/2 P⁻¹ τ[i]
        ω[i+½] = (m I + h/2 D)⁻¹ { exp(−h/2 Ω̂[i]^×) m ω[i] + h/2 τ[i] },   Ω̂ = Ω^m − b̂ − ω
        R̂[i+1] = R̂[i] exp(h (Ω^m[i+½] − b̂[i+½] − ω[i+½])^×)
        b̂[i+1] = b̂[i+½] + h/2 P⁻¹ τ[i+1]
        m ω[i+1] = exp(−h/2 Ω̂[i+1]^×) { (m I − h/2 D) ω[i+½] + h/2 τ[i+1] }

    With P⁻¹ = 0 and b̂ = 0 this is the paper's step, bit for bit.

    Returns ``(R̂[i+1], ω[i+1], b̂[i+1], Φ'(U⁰[i+1]) S_L[i+1], Newton updates, converged)``.
    """
    m = ep[P_M]
    hh = 0.5 * h
    wx, wy, wz = w
    b0x, b0y, b0z = b
    g0x, g0y, g0z = g0[0] - b0x, g0[1] - b0y, g0[2] - b0z  # Ω^m[i] − b̂[i]
    t0x, t0y, t0z = tau0
    bhx, bhy, bhz = bias_half_step(ep, b, hh, tau0, bl)
    # ω[i+½] = (m I + h/2 D)⁻¹ { exp(−h/2 Ω̂[i]^×) m ω[i] + h/2 τ[i] }
    vx, vy, vz = rotate_f(hh * (wx - g0x), hh * (wy - g0y), hh * (wz - g0z), m * wx, m * wy, m * wz)
    bx, by, bz = vx + hh * t0x, vy + hh * t0y, vz + hh * t0z
    d = P_D
    diagonal = ep[P_D_DIAG] != 0.0
    if diagonal:
        hx, hy, hz = bx / (m + hh * ep[d]), by / (m + hh * ep[d + 4]), bz / (m + hh * ep[d + 8])
    else:  # Cramer's rule on m I + h/2 D (symmetric positive definite: never singular)
        m0, m1, m2 = m + hh * ep[d], hh * ep[d + 1], hh * ep[d + 2]
        m3, m4, m5 = hh * ep[d + 3], m + hh * ep[d + 4], hh * ep[d + 5]
        m6, m7, m8 = hh * ep[d + 6], hh * ep[d + 7], m + hh * ep[d + 8]
        c0, c1, c2 = m4 * m8 - m5 * m7, m5 * m6 - m3 * m8, m3 * m7 - m4 * m6
        inv = 1.0 / (m0 * c0 + m1 * c1 + m2 * c2)
        hx = (c0 * bx + (m2 * m7 - m1 * m8) * by + (m1 * m5 - m2 * m4) * bz) * inv
        hy = (c1 * bx + (m0 * m8 - m2 * m6) * by + (m2 * m3 - m0 * m5) * bz) * inv
        hz = (c2 * bx + (m1 * m6 - m0 * m7) * by + (m0 * m4 - m1 * m3) * bz) * inv
    # R̂[i+1] = R̂[i] exp(h (Ω^m[i+½] − b̂[i+½] − ω[i+½])^×)
    g1x, g1y, g1z = g1
    f = 0.5 + ep[P_GYRO_DELAY] / h  # the step's rate: the readings at its middle, d later
    step = exp_f(
        h * (g0[0] + f * (g1x - g0[0]) - bhx - hx),
        h * (g0[1] + f * (g1y - g0[1]) - bhy - hy),
        h * (g0[2] + f * (g1z - g0[2]) - bhz - hz),
    )
    r1 = reorthonormalize_f(matmul_f(r, step))
    tau1 = torque(ep, r1, big_l, mask, k)
    t1x, t1y, t1z = tau1
    b1 = bias_half_step(ep, (bhx, bhy, bhz), hh, tau1, bl)
    # m ω[i+1] = exp(−h/2 Ω̂[i+1]^×) { (m I − h/2 D) ω[i+½] + h/2 τ[i+1] }
    if diagonal:
        c = (
            (m - hh * ep[d]) * hx + hh * t1x,
            (m - hh * ep[d + 4]) * hy + hh * t1y,
            (m - hh * ep[d + 8]) * hz + hh * t1z,
        )
    else:
        c = (
            m * hx - hh * (ep[d] * hx + ep[d + 1] * hy + ep[d + 2] * hz) + hh * t1x,
            m * hy - hh * (ep[d + 3] * hx + ep[d + 4] * hy + ep[d + 5] * hz) + hh * t1y,
            m * hz - hh * (ep[d + 6] * hx + ep[d + 7] * hy + ep[d + 8] * hz) + hh * t1z,
        )
    w1, iters, ok = newton(ep, hh, (g1x - b1[0], g1y - b1[1], g1z - b1[2]), c)
    return r1, w1, b1, tau1, iters, ok


@jitable
def usable_rate(gx: float, gy: float, gz: float) -> bool:
    """Whether a rate reading (rad/s) is usable: every axis a number within :data:`GYRO_LIMIT`."""
    return abs(gx) <= GYRO_LIMIT and abs(gy) <= GYRO_LIMIT and abs(gz) <= GYRO_LIMIT


@jitable
def step_in_range(ep, h: float) -> bool:  # type: ignore[no-untyped-def]
    """Whether ``h`` (s) is a step the estimator takes: positive, and at most :data:`MAX_SUBSTEPS`
    sub-steps of ``max_step_s`` (NaN and inf are neither)."""
    return 0.0 < h <= ep[P_MAX_STEP] * MAX_SUBSTEPS


@kernel
def step(ep, es, h, gx, gy, gz, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """Take one sample into the state ``es``: rates ``g`` (rad/s), accelerometer ``a`` and magnetometer
    ``m`` (any units), NaN meaning not usable, ``h`` s since the previous sample. The first sample (``es``
    not started) only initialises: it sets Ω^m[0] and the cached torque at R̂0, and ignores ``h``.
    A step longer than ``max_step_s`` is split into sub-steps (gyro interpolated linearly, measurement
    held). Counts into the state's counters; leaves the time slot to the callers.

    Returns the step's flags ``| newton_updates << ITER_SHIFT``, or :data:`BAD_STEP` (nothing changed)
    for a started estimator and an ``h`` that is not a positive number or is too long
    (:func:`step_in_range`)."""
    flags = 0
    if not usable_rate(gx, gy, gz):
        gx = gy = gz = 0.0
        flags |= GYR_STALE
    mask, big_l, k, mflags = measurement(ep, ax, ay, az, mx, my, mz, es[S_MAG_WEIGHT])
    flags |= mflags
    r = (es[0], es[1], es[2], es[3], es[4], es[5], es[6], es[7], es[8])
    g1 = (gx, gy, gz)
    total = 0
    if es[S_STARTED] == 0.0:
        es[S_STARTED] = 1.0
        tau = torque(ep, r, big_l, mask, k)
    else:
        if not step_in_range(ep, h):
            return BAD_STEP
        w = (es[S_OMEGA], es[S_OMEGA + 1], es[S_OMEGA + 2])
        b = (es[S_BIAS], es[S_BIAS + 1], es[S_BIAS + 2])
        na = math.sqrt(ax * ax + ay * ay + az * az)
        if na > 0.0 and math.isfinite(na):
            bl = (es[S_BIAS_TRUST], ax / na, ay / na, az / na)
        else:
            bl = (es[S_BIAS_TRUST], 0.0, 0.0, 0.0)
        g0 = (es[S_GYR], es[S_GYR + 1], es[S_GYR + 2])
        tau = (es[S_TORQUE], es[S_TORQUE + 1], es[S_TORQUE + 2])
        max_step = ep[P_MAX_STEP]
        if h <= max_step:
            r, w, b, tau, total, ok = advance(ep, r, w, b, g0, tau, h, g1, big_l, mask, k, bl)
            if not ok:
                flags |= NEWTON_FAILED
        else:  # sub-steps: gyro interpolated linearly, measurement held
            n_sub = int(math.ceil(h / max_step))
            a0, a1, a2 = g0
            flags |= SUBSTEPPED
            for j in range(1, n_sub + 1):
                f = j / n_sub
                ga = (a0 + f * (gx - a0), a1 + f * (gy - a1), a2 + f * (gz - a2)) if j < n_sub else g1
                r, w, b, tau, iters, ok = advance(ep, r, w, b, g0, tau, h / n_sub, ga, big_l, mask, k, bl)
                g0 = ga
                total += iters
                if not ok:
                    flags |= NEWTON_FAILED
            es[S_COUNTS + C_SUBSTEPS] += n_sub - 1
        for i in range(9):
            es[S_R + i] = r[i]
        es[S_OMEGA], es[S_OMEGA + 1], es[S_OMEGA + 2] = w
        es[S_BIAS], es[S_BIAS + 1], es[S_BIAS + 2] = b
    es[S_GYR], es[S_GYR + 1], es[S_GYR + 2] = g1
    es[S_TORQUE], es[S_TORQUE + 1], es[S_TORQUE + 2] = tau
    for i in range(3):
        es[S_RATE + i] = es[S_GYR + i] - es[S_BIAS + i] - es[S_OMEGA + i]
    c = S_COUNTS
    es[c + C_STEPS] += 1.0
    es[c + C_NEWTON_UPDATES] += total
    es[c + C_MAX_NEWTON_UPDATES] = max(es[c + C_MAX_NEWTON_UPDATES], total)
    if flags & NEWTON_FAILED:
        es[c + C_NEWTON_FAILURES] += 1.0
    if flags & DEGENERATE:
        es[c + C_DEGENERATE] += 1.0
    if flags & GYR_STALE:
        es[c + C_GYRO_MISSING] += 1.0
    if mask == 0:
        es[c + C_NO_DIRECTION] += 1.0
    return flags | (total << ITER_SHIFT)


@kernel
def update(ep, es, dt, gx, gy, gz, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """:func:`step` for one live sample, ``dt`` s after the previous one (added to the time slot).
    Returns what :func:`step` returns."""
    started = es[S_STARTED] != 0.0
    code = step(ep, es, dt, gx, gy, gz, ax, ay, az, mx, my, mz)
    if code >= 0 and started:
        es[S_T] += dt
    return code


@kernel
def write_row(es, i, out_r, out_omega, out_w):  # type: ignore[no-untyped-def]
    """The estimate in ``es`` into row ``i`` of R̂ (N, 3, 3), Ω̂ and ω (N, 3)."""
    for a in range(3):
        for b in range(3):
            out_r[i, a, b] = es[S_R + 3 * a + b]
        out_omega[i, a] = es[S_RATE + a]
        out_w[i, a] = es[S_OMEGA + a]


@kernel
def run(ep, es, t, flags_in, gyr, acc, mag, out_r, out_omega, out_w, out_flags, out_iters):  # type: ignore[no-untyped-def]
    """:func:`step` over N merged steps at times ``t`` (N,) s, strictly increasing and after the state's
    time (the caller checks): ``gyr``, ``acc``, ``mag`` (N, 3), a sensor flagged stale in ``flags_in``
    (N,) being not usable. A state not started adopts ``t[0]`` as its time. Writes R̂ (N, 3, 3), Ω̂ and ω
    (N, 3), flags (``flags_in`` | the step's) and Newton updates (N,). With the "raise" failure policy it
    stops after the first step whose Newton solve failed; returns the number of steps taken."""
    n = t.shape[0]
    stop = ep[P_RAISE] != 0.0
    nan = math.nan
    for i in range(n):
        fi = flags_in[i]
        gx, gy, gz = (nan, nan, nan) if fi & GYR_STALE else (gyr[i, 0], gyr[i, 1], gyr[i, 2])
        ax, ay, az = (nan, nan, nan) if fi & ACC_STALE else (acc[i, 0], acc[i, 1], acc[i, 2])
        mx, my, mz = (nan, nan, nan) if fi & MAG_STALE else (mag[i, 0], mag[i, 1], mag[i, 2])
        h = t[i] - es[S_T] if es[S_STARTED] != 0.0 else 0.0
        code = step(ep, es, h, gx, gy, gz, ax, ay, az, mx, my, mz)
        if code < 0:  # a time not after the previous one: the caller checks, this is the backstop
            return i
        es[S_T] = t[i]
        write_row(es, i, out_r, out_omega, out_w)
        out_flags[i] = fi | (code & FLAG_BITS)
        out_iters[i] = code >> ITER_SHIFT
        if stop and code & NEWTON_FAILED:
            return i + 1
    return n

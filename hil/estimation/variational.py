"""The step of the paper's second-order discrete variational attitude estimator (Viswanathan, Sanyal &
Izadi, arXiv 1509.03677, Proposition 1; Izadi & Sanyal, Automatica 2014): the measurement terms, the
potential's torque, the implicit step's Newton solve and the float kernels that
:class:`hil.estimation.estimator.VariationalEstimator` runs. Pure math, no I/O.

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

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.estimation.params import EstimatorParams
from hil.estimation.sensors import StepFlag
from hil.so3 import Mat9, Vec3, matmul_f, reorthonormalize_f, rodrigues_coefficients, rotate_f, solve3_f
from protocol.errors import ConvergenceError

Array = NDArray[np.float64]

_ACC, _MAG, _CROSS = 1, 2, 4  # bits of the usable-direction mask (index into per-mask tables)
_NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)
_SUBSTEPPED = int(StepFlag.SUBSTEPPED)


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

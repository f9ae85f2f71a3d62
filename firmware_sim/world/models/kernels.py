"""The plant step compiled: :meth:`.plant.Plant.step` (the numpy reference) for one run, on flat float64
arrays, in the order the reference takes it — configuration (gimbal frames, rotor inertia turned by φ
for non-axisymmetric rotors, locked inertia J, the mass matrix's columns b_γ, b_φ and 2×2 block inverses),
velocities (the 3×3 Schur complement solved by its adjugate), body rates and gyroscopic forces, motor
torques (:func:`.drives.drive_torques`), the gravity-gradient moment, Rodrigues' exp, dexp⁻¹ and the final
Newton–Schulz correction. :mod:`.compiled` wraps these for Python callers; docs/dynamics.md derives the
equations.

Layouts (n units):

- model (:func:`model_size`): ``[n, axisymmetric, gravity, mean motion, 3 n², r̂₀ (3), n̂ × r̂₀ (3), J₀ (9)]``
  then per unit ``[s₀ (3), t₀ (3), g (3), Ī_G (9), Ī_W (9), D⁻¹ (3) (constant when axisymmetric)]``.
- state (:func:`state_size`): ``[t, R (9, row-major), π (3), γ (n), φ (n), p_γ (n), p_φ (n), Ω (3), γ̇ (n),
  φ̇ (n)]`` — the integrated variables ``x`` as :meth:`Plant.step` stacks them, then the velocities.
- path row (:data:`PATH_WIDTH`): ``[t, R (9), Ω (3)]``, one per state visited (the phone samples along it);
  or, in a path :func:`state_size` wide, the whole state (a world that looks ahead and may go back).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.jit import kernel

from .drives import drive_torques

Array = NDArray[np.float64]

OK, BAD_TORQUE, SINGULAR, DIVERGED = 0, 1, 2, 3
""":func:`advance`'s status: done; a motor torque was not finite; singular mass matrix; state not finite."""

M_HEADER = 20  # model: n, axisymmetric, gravity, mean motion, 3n², r̂₀, n̂×r̂₀, J₀
M_UNIT = 30  # per unit: s₀, t₀, g, Ī_G, Ī_W, D⁻¹
PATH_WIDTH = 13
MAX_TIME_S = 2.0**33
"""The farthest time (s, either side of zero) the world's plant and phone take (~272 years): beyond it
float64 spaces times more than 1 µs apart (the protocol's timestamp unit), so a step or a sample period is
no longer what it says. At 1e16 s adding a phone's sample period left its next sample time unchanged and
sampling never ended; at 1e17 s a plant step of 1 ms left its clock where it was."""
_GEO = 21  # per unit geometry: s(γ) (3), t(γ) (3), Ī_W^G (9), b_γ (3), b_φ (3)... D⁻¹ kept apart
_TWO_PI = 2.0 * math.pi


def model_size(n: int) -> int:
    return M_HEADER + M_UNIT * n


def state_size(n: int) -> int:
    return 16 + 6 * n


def work_size(n: int) -> int:
    """Floats of scratch :func:`advance` needs."""
    return 64 + 40 * n + 12 * (3 + 4 * n)


# --------------------------------------------------------------------------- SO(3) on 9-vectors
@kernel
def exp9(p0: float, p1: float, p2: float, out: Array) -> None:
    """``exp(φ^×)`` (row-major) as the reference's ``_exp``: series below θ = 1e-4 rad."""
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 < 1e-8:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        q = math.sin(0.5 * th) / th
        b = 2.0 * (q * q)
    out[0] = 1.0 - b * (p1 * p1 + p2 * p2)
    out[1] = b * (p0 * p1) - a * p2
    out[2] = b * (p0 * p2) + a * p1
    out[3] = b * (p0 * p1) + a * p2
    out[4] = 1.0 - b * (p0 * p0 + p2 * p2)
    out[5] = b * (p1 * p2) - a * p0
    out[6] = b * (p0 * p2) - a * p1
    out[7] = b * (p1 * p2) + a * p0
    out[8] = 1.0 - b * (p0 * p0 + p1 * p1)


@kernel
def _matmul(p: Array, q: Array, out: Array) -> None:
    for r in range(3):
        for c in range(3):
            out[3 * r + c] = p[3 * r] * q[c] + p[3 * r + 1] * q[3 + c] + p[3 * r + 2] * q[6 + c]


@kernel
def _turn(R0: Array, p0: float, p1: float, p2: float, e: Array, out: Array) -> None:
    """``R₀ exp(φ^×)`` into ``out`` (``e`` scratch of 9)."""
    exp9(p0, p1, p2, e)
    _matmul(R0, e, out)


@kernel
def _reorthonormalize(r: Array, out: Array) -> None:
    """One Newton–Schulz polar step ``R (3I − RᵀR)/2``."""
    e00 = 0.5 * (1.0 - (r[0] * r[0] + r[3] * r[3] + r[6] * r[6]))
    e11 = 0.5 * (1.0 - (r[1] * r[1] + r[4] * r[4] + r[7] * r[7]))
    e22 = 0.5 * (1.0 - (r[2] * r[2] + r[5] * r[5] + r[8] * r[8]))
    e01 = -0.5 * (r[0] * r[1] + r[3] * r[4] + r[6] * r[7])
    e02 = -0.5 * (r[0] * r[2] + r[3] * r[5] + r[6] * r[8])
    e12 = -0.5 * (r[1] * r[2] + r[4] * r[5] + r[7] * r[8])
    for k in range(3):
        a, b, c = r[3 * k], r[3 * k + 1], r[3 * k + 2]
        out[3 * k] = a + a * e00 + b * e01 + c * e02
        out[3 * k + 1] = b + a * e01 + b * e11 + c * e12
        out[3 * k + 2] = c + a * e02 + b * e12 + c * e22


@kernel
def _dexpinv(th: Array, w: Array, out: Array) -> None:
    """``w − ½ Θ×w + (1/12) Θ×(Θ×w)``."""
    c0 = th[1] * w[2] - th[2] * w[1]
    c1 = th[2] * w[0] - th[0] * w[2]
    c2 = th[0] * w[1] - th[1] * w[0]
    out[0] = w[0] - 0.5 * c0 + (th[1] * c2 - th[2] * c1) / 12.0
    out[1] = w[1] - 0.5 * c1 + (th[2] * c0 - th[0] * c2) / 12.0
    out[2] = w[2] - 0.5 * c2 + (th[0] * c1 - th[1] * c0) / 12.0


# --------------------------------------------------------------------------- the model
@kernel
def _configure(model: Array, n: int, x: Array, geo: Array, dinv: Array, J: Array) -> None:
    """Per unit ``geo[i] = [s(γ), t(γ), Ī_W^G, b_γ, b_φ]`` and ``dinv[i]``, and J(γ, φ), at the angles in
    ``x`` (:func:`hil.vscmg.model.configuration`)."""
    axisym = model[1] != 0.0
    for k in range(9):
        J[k] = model[11 + k]
    for i in range(n):
        u = M_HEADER + M_UNIT * i
        g = geo[i]
        c, s = math.cos(x[3 + i]), math.sin(x[3 + i])
        for k in range(3):
            g[k] = c * model[u + k] + s * model[u + 3 + k]  # s(γ)
            g[3 + k] = c * model[u + 3 + k] - s * model[u + k]  # t(γ)
        w = g[6:15]
        d = dinv[i]
        if axisym:
            for k in range(9):
                w[k] = model[u + 18 + k]
            d[0], d[1], d[2] = model[u + 27], model[u + 28], model[u + 29]
        else:  # Rx(φ) Ī_W Rx(φ)ᵀ
            cp, sp = math.cos(x[3 + n + i]), math.sin(x[3 + n + i])
            a, b, cc = model[u + 18], model[u + 19], model[u + 20]
            dd, e, f = model[u + 22], model[u + 23], model[u + 26]
            w[0] = a
            w[1] = w[3] = b * cp - cc * sp
            w[2] = w[6] = b * sp + cc * cp
            w[4] = cp * cp * dd - 2.0 * cp * sp * e + sp * sp * f
            w[5] = w[7] = cp * sp * (dd - f) + (cp * cp - sp * sp) * e
            w[8] = sp * sp * dd + 2.0 * cp * sp * e + cp * cp * f
            k22 = model[u + 17] + w[8]
            det = k22 * w[0] - w[6] * w[6]
            d[0], d[1], d[2] = w[0] / det, -w[6] / det, k22 / det
        # M = C K̄ (C's columns s, t, g), J += M Cᵀ, b_γ = M e_g, b_φ = C Ī_W^G e_s
        for r in range(3):
            cs, ct, cg = g[r], g[3 + r], model[u + 6 + r]
            m0 = cs * (model[u + 9] + w[0]) + ct * (model[u + 12] + w[3]) + cg * (model[u + 15] + w[6])
            m1 = cs * (model[u + 10] + w[1]) + ct * (model[u + 13] + w[4]) + cg * (model[u + 16] + w[7])
            m2 = cs * (model[u + 11] + w[2]) + ct * (model[u + 14] + w[5]) + cg * (model[u + 17] + w[8])
            for q in range(3):
                J[3 * r + q] += m0 * g[q] + m1 * g[3 + q] + m2 * model[u + 6 + q]
            g[15 + r] = m2
            g[18 + r] = cs * w[0] + ct * w[3] + cg * w[6]


@kernel
def _velocities(n: int, geo: Array, dinv: Array, J: Array, H: Array, x: Array, v: Array) -> bool:
    """Solve ``M ν = (Π, p_γ, p_φ)`` into ``v = [Ω, γ̇, φ̇]`` (:func:`hil.vscmg.model.velocities`);
    False for a singular Schur complement."""
    s00, s01, s02, s10, s11, s12, s20, s21, s22 = J[0], J[1], J[2], J[3], J[4], J[5], J[6], J[7], J[8]
    h0, h1, h2 = H[0], H[1], H[2]
    for i in range(n):
        bg, bp = geo[i, 15:18], geo[i, 18:21]
        i11, i12, i22 = dinv[i, 0], dinv[i, 1], dinv[i, 2]
        pg, pp = x[3 + 2 * n + i], x[3 + 3 * n + i]
        ug0, ug1, ug2 = i11 * bg[0] + i12 * bp[0], i11 * bg[1] + i12 * bp[1], i11 * bg[2] + i12 * bp[2]
        up0, up1, up2 = i12 * bg[0] + i22 * bp[0], i12 * bg[1] + i22 * bp[1], i12 * bg[2] + i22 * bp[2]
        s00 -= ug0 * bg[0] + up0 * bp[0]
        s01 -= ug0 * bg[1] + up0 * bp[1]
        s02 -= ug0 * bg[2] + up0 * bp[2]
        s10 -= ug1 * bg[0] + up1 * bp[0]
        s11 -= ug1 * bg[1] + up1 * bp[1]
        s12 -= ug1 * bg[2] + up1 * bp[2]
        s20 -= ug2 * bg[0] + up2 * bp[0]
        s21 -= ug2 * bg[1] + up2 * bp[1]
        s22 -= ug2 * bg[2] + up2 * bp[2]
        h0 -= ug0 * pg + up0 * pp
        h1 -= ug1 * pg + up1 * pp
        h2 -= ug2 * pg + up2 * pp
    c00 = s11 * s22 - s12 * s21
    c01 = s12 * s20 - s10 * s22
    c02 = s10 * s21 - s11 * s20
    det = s00 * c00 + s01 * c01 + s02 * c02
    if det == 0.0:
        return False
    o0 = (c00 * h0 + (s02 * s21 - s01 * s22) * h1 + (s01 * s12 - s02 * s11) * h2) / det
    o1 = (c01 * h0 + (s00 * s22 - s02 * s20) * h1 + (s02 * s10 - s00 * s12) * h2) / det
    o2 = (c02 * h0 + (s01 * s20 - s00 * s21) * h1 + (s00 * s11 - s01 * s10) * h2) / det
    v[0], v[1], v[2] = o0, o1, o2
    for i in range(n):
        bg, bp = geo[i, 15:18], geo[i, 18:21]
        rg = x[3 + 2 * n + i] - (bg[0] * o0 + bg[1] * o1 + bg[2] * o2)
        rp = x[3 + 3 * n + i] - (bp[0] * o0 + bp[1] * o1 + bp[2] * o2)
        v[3 + i] = dinv[i, 0] * rg + dinv[i, 1] * rp
        v[3 + n + i] = dinv[i, 1] * rg + dinv[i, 2] * rp
    return True


@kernel
def _forces(model: Array, n: int, geo: Array, v: Array, fg: Array, fp: Array) -> None:
    """``(∂T/∂γ, ∂T/∂φ)`` (:func:`hil.vscmg.model.body_rates`, :func:`hil.vscmg.model.internal_forces`)."""
    o0, o1, o2 = v[0], v[1], v[2]
    for i in range(n):
        u = M_HEADER + M_UNIT * i
        g = geo[i]
        # ω_G = Cᵀ Ω + γ̇ e_g, ω_W = ω_G + φ̇ e_s (gimbal-frame components)
        v0 = g[0] * o0 + g[1] * o1 + g[2] * o2
        v1 = g[3] * o0 + g[4] * o1 + g[5] * o2
        v2 = model[u + 6] * o0 + model[u + 7] * o1 + model[u + 8] * o2 + v[3 + i]
        wr = v[3 + n + i]
        q0 = v0 + wr
        hg0 = model[u + 9] * v0 + model[u + 10] * v1 + model[u + 11] * v2
        hg1 = model[u + 12] * v0 + model[u + 13] * v1 + model[u + 14] * v2
        hw0 = g[6] * q0 + g[7] * v1 + g[8] * v2
        hw1 = g[9] * q0 + g[10] * v1 + g[11] * v2
        hw2 = g[12] * q0 + g[13] * v1 + g[14] * v2
        fg[i] = -(v0 * hg1 - v1 * hg0) - (q0 * hw1 - v1 * hw0) + wr * hw1
        fp[i] = -(v1 * hw2 - v2 * hw1)


@kernel
def _gravity(model: Array, t: float, R: Array, J: Array, out: Array) -> None:
    """``R τ`` (inertial) with ``τ = 3 n² r̂ × J r̂`` (:meth:`.plant.GravityGradient.torque`)."""
    ang = model[3] * t
    ca, sa = math.cos(ang), math.sin(ang)
    e0 = ca * model[5] + sa * model[8]
    e1 = ca * model[6] + sa * model[9]
    e2 = ca * model[7] + sa * model[10]
    b0 = R[0] * e0 + R[3] * e1 + R[6] * e2  # r̂ in the body: Rᵀ e
    b1 = R[1] * e0 + R[4] * e1 + R[7] * e2
    b2 = R[2] * e0 + R[5] * e1 + R[8] * e2
    j0 = J[0] * b0 + J[1] * b1 + J[2] * b2
    j1 = J[3] * b0 + J[4] * b1 + J[5] * b2
    j2 = J[6] * b0 + J[7] * b1 + J[8] * b2
    k = model[4]
    t0 = k * (b1 * j2 - b2 * j1)
    t1 = k * (b2 * j0 - b0 * j2)
    t2 = k * (b0 * j1 - b1 * j0)
    out[0] = R[0] * t0 + R[1] * t1 + R[2] * t2
    out[1] = R[3] * t0 + R[4] * t1 + R[5] * t2
    out[2] = R[6] * t0 + R[7] * t1 + R[8] * t2


@kernel
def _derivative(
    model: Array,
    n: int,
    t: float,
    R: Array,
    x: Array,
    known: bool,
    v: Array,
    mode: int,
    drive: Array,
    f: Array,
    geo: Array,
    dinv: Array,
    J: Array,
    tq: Array,
) -> int:
    """``ẋ`` into ``f`` at one stage, and the velocities into ``v`` (already there when ``known``: the first
    stage reuses the state's). ``tq`` (2n + 3) receives the motor torques (and serves as scratch)."""
    _configure(model, n, x, geo, dinv, J)
    if not known:
        H = tq[2 * n : 2 * n + 3]
        for k in range(3):
            H[k] = R[k] * x[0] + R[3 + k] * x[1] + R[6 + k] * x[2]
        if not _velocities(n, geo, dinv, J, H, x, v):
            return SINGULAR
    fg, fp = f[3 + 2 * n : 3 + 3 * n], f[3 + 3 * n : 3 + 4 * n]
    _forces(model, n, geo, v, fg, fp)
    ug, us = tq[0:n], tq[n : 2 * n]
    if not drive_torques(mode, drive, n, x[3 : 3 + n], v[3 : 3 + n], v[3 + n : 3 + 2 * n], fg, fp, ug, us):
        return BAD_TORQUE
    if mode != 0:
        for i in range(n):
            fg[i] += ug[i]
            fp[i] += us[i]
    if model[2] != 0.0:
        _gravity(model, t, R, J, f)
    else:
        f[0] = f[1] = f[2] = 0.0
    for i in range(2 * n):
        f[3 + i] = v[3 + i]
    return OK


# --------------------------------------------------------------------------- the step
@kernel
def advance(
    model: Array, state: Array, h: float, steps: int, mode: int, drive: Array, path: Array, work: Array
) -> tuple[int, int]:
    """``steps`` RKMK4 steps of ``h`` seconds on ``state`` (in place) under the drive ``(mode, drive)``;
    with ``path`` (steps + 1, :data:`PATH_WIDTH` or :func:`state_size`) rows, the start and every state
    reached are written to it. Returns ``(status, steps done)``; on an error the state is the last good
    one and ``work[:2n+1]`` holds the stage time and the offending torques (:data:`BAD_TORQUE`) or
    nothing."""
    n = int(model[0])
    nx = 3 + 4 * n
    nv = 3 + 2 * n
    o = 0
    geo = work[o : o + _GEO * n].reshape((n, _GEO))
    o += _GEO * n
    dinv = work[o : o + 3 * n].reshape((n, 3))
    o += 3 * n
    J = work[o : o + 9]
    o += 9
    tq = work[o : o + 2 * n + 3]
    o += 2 * n + 3
    e, Rs, Rn = work[o : o + 9], work[o + 9 : o + 18], work[o + 18 : o + 27]
    o += 27
    th, dd, ws = work[o : o + 3], work[o + 3 : o + 6], work[o + 6 : o + 9]
    o += 9
    xs, xn = work[o : o + nx], work[o + nx : o + 2 * nx]
    o += 2 * nx
    f1, f2, f3, f4 = (
        work[o : o + nx],
        work[o + nx : o + 2 * nx],
        work[o + 2 * nx : o + 3 * nx],
        work[o + 3 * nx : o + 4 * nx],
    )
    o += 4 * nx
    v1, vs = work[o : o + nv], work[o + nv : o + 2 * nv]
    o += 2 * nv
    record = path.shape[0] > 0
    if record:
        _record(state, n, path[0])
    for k in range(steps):
        t0 = state[0]
        R0, x0 = state[1:10], state[10 : 10 + nx]
        for i in range(nv):
            v1[i] = state[10 + nx + i]
        hh = 0.5 * h
        st = _derivative(model, n, t0, R0, x0, True, v1, mode, drive, f1, geo, dinv, J, tq)
        if st != OK:
            return _fail(st, work, t0, tq, 2 * n if st == BAD_TORQUE else 0), k
        w1 = v1[0:3]
        for i in range(3):
            th[i] = hh * w1[i]
        _turn(R0, th[0], th[1], th[2], e, Rs)
        for i in range(nx):
            xs[i] = x0[i] + hh * f1[i]
        st = _derivative(model, n, t0 + hh, Rs, xs, False, vs, mode, drive, f2, geo, dinv, J, tq)
        if st != OK:
            return _fail(st, work, t0 + hh, tq, 2 * n if st == BAD_TORQUE else 0), k
        _dexpinv(th, vs, dd)
        ws[0], ws[1], ws[2] = w1[0] + 2.0 * dd[0], w1[1] + 2.0 * dd[1], w1[2] + 2.0 * dd[2]
        for i in range(3):
            th[i] = hh * dd[i]
        _turn(R0, th[0], th[1], th[2], e, Rs)
        for i in range(nx):
            xs[i] = x0[i] + hh * f2[i]
        st = _derivative(model, n, t0 + hh, Rs, xs, False, vs, mode, drive, f3, geo, dinv, J, tq)
        if st != OK:
            return _fail(st, work, t0 + hh, tq, 2 * n if st == BAD_TORQUE else 0), k
        _dexpinv(th, vs, dd)
        for i in range(3):
            ws[i] = ws[i] + 2.0 * dd[i]
            th[i] = h * dd[i]
        _turn(R0, th[0], th[1], th[2], e, Rs)
        for i in range(nx):
            xs[i] = x0[i] + h * f3[i]
        st = _derivative(model, n, t0 + h, Rs, xs, False, vs, mode, drive, f4, geo, dinv, J, tq)
        if st != OK:
            return _fail(st, work, t0 + h, tq, 2 * n if st == BAD_TORQUE else 0), k
        _dexpinv(th, vs, dd)
        h6 = h / 6.0
        _turn(R0, h6 * (ws[0] + dd[0]), h6 * (ws[1] + dd[1]), h6 * (ws[2] + dd[2]), e, Rs)
        _reorthonormalize(Rs, Rn)
        finite = True
        for i in range(nx):
            xn[i] = x0[i] + h6 * (f1[i] + 2.0 * f2[i] + 2.0 * f3[i] + f4[i])
            if not math.isfinite(xn[i]):
                finite = False
        for i in range(9):  # a step far too long leaves π and the angles finite but the attitude NaN
            if not math.isfinite(Rn[i]):
                finite = False
        if not finite:
            return _fail(DIVERGED, work, t0 + h, tq, 0), k
        for i in range(n):
            xn[3 + n + i] = xn[3 + n + i] % _TWO_PI
        _configure(model, n, xn, geo, dinv, J)
        H = tq[2 * n : 2 * n + 3]
        for i in range(3):
            H[i] = Rn[i] * xn[0] + Rn[3 + i] * xn[1] + Rn[6 + i] * xn[2]
        if not _velocities(n, geo, dinv, J, H, xn, vs):
            return _fail(SINGULAR, work, t0 + h, tq, 0), k
        for i in range(nv):  # the velocities read from it too (the reference's check, in the same order)
            if not math.isfinite(vs[i]):
                return _fail(DIVERGED, work, t0 + h, tq, 0), k
        state[0] = t0 + h
        for i in range(9):
            state[1 + i] = Rn[i]
        for i in range(nx):
            state[10 + i] = xn[i]
        for i in range(nv):
            state[10 + nx + i] = vs[i]
        if record:
            _record(state, n, path[k + 1])
    return OK, steps


@kernel
def _record(state: Array, n: int, row: Array) -> None:
    if row.shape[0] != PATH_WIDTH:  # a row as wide as the state: all of it
        for i in range(row.shape[0]):
            row[i] = state[i]
        return
    for i in range(10):
        row[i] = state[i]
    for i in range(3):
        row[10 + i] = state[13 + 4 * n + i]


@kernel
def _fail(status: int, work: Array, t: float, tq: Array, count: int) -> int:
    """Leave the stage time and the first ``count`` motor torques at the start of ``work`` (for the error
    message; ``tq`` lies further on in ``work``)."""
    work[0] = t
    for i in range(count):
        work[1 + i] = tq[i]
    return status

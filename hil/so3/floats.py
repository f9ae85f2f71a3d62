"""SO(3) per-step kernels on Python floats. Pure math.

The estimator and the plant step one sample at a time; on 3-vectors and 3×3 matrices numpy's per-call
overhead (~1 µs) dominates the arithmetic, so these kernels work on Python floats: vectors are 3-tuples,
matrices 9-tuples in row-major order. They agree with :mod:`hil.so3.arrays` to rounding.

The ones marked ``@jitable`` are also callable from inside compiled kernels (numba compiles them
into the caller: the estimator's kernels use them); called from Python they are these plain functions.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from hil.jit import jitable
from protocol.errors import NumericalError

from .arrays import _SMALL

Vec3 = tuple[float, float, float]
Mat9 = tuple[float, float, float, float, float, float, float, float, float]


_C_SERIES = tuple(1.0 / math.factorial(2 * k + 3) for k in range(9))


def mat9(R: ArrayLike) -> Mat9:
    """A (3, 3) matrix as a row-major 9-tuple of floats (from Python: numpy in, floats out)."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = np.asarray(R, dtype=float).reshape(9).tolist()
    return (m0, m1, m2, m3, m4, m5, m6, m7, m8)


def vec3(v: ArrayLike) -> Vec3:
    """A (3,) vector as a 3-tuple of floats."""
    x, y, z = np.asarray(v, dtype=float).reshape(3).tolist()
    return (x, y, z)


@jitable
def rodrigues_coefficients(theta2: float) -> tuple[float, float, float]:
    """``(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³)`` for ``θ² = theta2``, each to full precision.

    ``exp(φ^×) = I + a φ^× + b (φ^×)²`` and the left Jacobian ``J_l(φ) = I + b φ^× + c (φ^×)²``. Taylor
    series below 1e-4 rad; ``b`` by the half-angle form ``2 sin²(θ/2)/θ²`` and ``c`` by its series below
    1 rad (their closed forms lose up to half the digits to cancellation at small θ).
    """
    if theta2 == math.inf:  # θ² overflowed: each coefficient's limit (each is below 2/θ < 1.5e-154 there);
        return 0.0, 0.0, 0.0  # math.sin(inf) raised a bare ValueError here, and gave NaN when compiled
    if theta2 < _SMALL * _SMALL:
        return (
            1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0,
            0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0,
            1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0,
        )
    theta = math.sqrt(theta2)
    s = math.sin(theta)
    half = math.sin(0.5 * theta)
    if theta2 < 1.0:  # Σ (−θ²)^k / (2k + 3)!, Horner, to θ¹⁶/19! < 1e-17
        c = _C_SERIES[-1]
        for coef in _C_SERIES[-2::-1]:
            c = coef - theta2 * c
    else:
        c = (theta - s) / (theta2 * theta)
    return s / theta, 2.0 * half * half / theta2, c


@jitable
def _turn_of_long_vector(px: float, py: float, pz: float) -> tuple[float, float, float, float, float]:
    """``(sin θ, 1 − cos θ, n)`` for a finite rotation vector ``φ = θ n`` (rad) whose ``|φ|²`` overflows
    float64 (``|φ|`` > 1.3e154 rad), so that Rodrigues' ``I + a φ^× + b (φ^×)²`` becomes
    ``I + sin θ n^× + (1 − cos θ) (n^×)²`` with the unit axis ``n``.

    θ/2 is taken from ``φ`` scaled by its largest component, and θ's sine and versine by the double-angle
    forms: θ itself overflows for ``|φ|`` beyond 1.8e308 rad, θ/2 never does. Before, ``θ² = inf`` made
    :func:`exp_f` and :func:`rotate_f` raise a bare ValueError (math.sin(inf)) from Python, return NaN from
    the compiled kernels and :func:`hil.so3.exp` a NaN matrix."""
    largest = max(abs(px), abs(py), abs(pz))
    ux, uy, uz = px / largest, py / largest, pz / largest
    length = math.sqrt(ux * ux + uy * uy + uz * uz)  # in [1, √3]
    half = (0.5 * largest) * length  # θ/2, finite for every finite φ
    s, c = math.sin(half), math.cos(half)
    return 2.0 * s * c, 2.0 * s * s, ux / length, uy / length, uz / length


@jitable
def _rodrigues_turn(px: float, py: float, pz: float) -> tuple[float, float, float, float, float]:
    """``(a, b, x, y, z)`` with ``exp(φ^×) = I + a v^× + b (v^×)²`` for ``v = (x, y, z)``: ``φ`` itself and
    :func:`rodrigues_coefficients`, or, for a finite ``φ`` too long to square, the same turn about its
    unit axis (:func:`_turn_of_long_vector`). :func:`exp_f` and :func:`rotate_f` both start here."""
    theta2 = px * px + py * py + pz * pz
    if theta2 == math.inf:
        return _turn_of_long_vector(px, py, pz)
    a, b, _ = rodrigues_coefficients(theta2)
    return a, b, px, py, pz


@jitable
def rotate_f(px: float, py: float, pz: float, vx: float, vy: float, vz: float) -> Vec3:
    """``exp(φ^×) v`` for ``φ = (px, py, pz)`` without forming the matrix (Rodrigues on the vector)."""
    a, b, px, py, pz = _rodrigues_turn(px, py, pz)
    cx = py * vz - pz * vy
    cy = pz * vx - px * vz
    cz = px * vy - py * vx
    return (
        vx + a * cx + b * (py * cz - pz * cy),
        vy + a * cy + b * (pz * cx - px * cz),
        vz + a * cz + b * (px * cy - py * cx),
    )


@jitable
def exp_f(px: float, py: float, pz: float) -> Mat9:
    """``exp(φ^×)`` as a row-major 9-tuple (Rodrigues); a rotation for every finite ``φ`` (rad)."""
    a, b, px, py, pz = _rodrigues_turn(px, py, pz)
    xx, yy, zz, xy, xz, yz = px * px, py * py, pz * pz, px * py, px * pz, py * pz
    return (
        1.0 - b * (yy + zz), b * xy - a * pz, b * xz + a * py,
        b * xy + a * pz, 1.0 - b * (xx + zz), b * yz - a * px,
        b * xz - a * py, b * yz + a * px, 1.0 - b * (xx + yy),
    )  # fmt: skip


@jitable
def log_f(r: Mat9) -> Vec3:
    """The rotation vector (|φ| ≤ π) of the row-major 9-tuple ``r``, as :func:`hil.so3.log` (the numpy
    reference) to rounding: θ by atan2; near π the axis from the symmetric part, its sign from the skew
    part. The one float version: the simulated phone's compiled sampler and the telemetry rows call it."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    c = min(max((r0 + r4 + r8 - 1.0) * 0.5, -1.0), 1.0)
    w0, w1, w2 = 0.5 * (r7 - r5), 0.5 * (r2 - r6), 0.5 * (r3 - r1)
    s = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    theta = math.atan2(s, c)
    if theta < _SMALL:
        k = 1.0 + theta * theta / 6.0
        return w0 * k, w1 * k, w2 * k
    if theta < math.pi - 1e-3:
        k = theta / s
        return w0 * k, w1 * k, w2 * k
    d0, d1, d2 = r0 - c, r4 - c, r8 - c  # the diagonal of (R + Rᵀ)/2 − cos θ I = (1 − cos θ) n nᵀ
    if d0 >= d1 and d0 >= d2:  # its largest entry's column
        n0, n1, n2 = d0, 0.5 * (r3 + r1), 0.5 * (r6 + r2)
    elif d1 >= d2:
        n0, n1, n2 = 0.5 * (r1 + r3), d1, 0.5 * (r7 + r5)
    else:
        n0, n1, n2 = 0.5 * (r2 + r6), 0.5 * (r5 + r7), d2
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if n0 * w0 + n1 * w1 + n2 * w2 < 0.0:
        norm = -norm
    return n0 / norm * theta, n1 / norm * theta, n2 / norm * theta


@jitable
def matmul_f(p: Mat9, q: Mat9) -> Mat9:
    """``p @ q`` for row-major 9-tuples."""
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = p
    q0, q1, q2, q3, q4, q5, q6, q7, q8 = q
    return (
        p0 * q0 + p1 * q3 + p2 * q6, p0 * q1 + p1 * q4 + p2 * q7, p0 * q2 + p1 * q5 + p2 * q8,
        p3 * q0 + p4 * q3 + p5 * q6, p3 * q1 + p4 * q4 + p5 * q7, p3 * q2 + p4 * q5 + p5 * q8,
        p6 * q0 + p7 * q3 + p8 * q6, p6 * q1 + p7 * q4 + p8 * q7, p6 * q2 + p7 * q5 + p8 * q8,
    )  # fmt: skip


@jitable
def apply_f(m: Mat9, v: Vec3) -> Vec3:
    """``m @ v`` for a row-major 9-tuple and a 3-tuple."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    x, y, z = v
    return (m0 * x + m1 * y + m2 * z, m3 * x + m4 * y + m5 * z, m6 * x + m7 * y + m8 * z)


@jitable
def apply_transpose_f(m: Mat9, v: Vec3) -> Vec3:
    """``m.T @ v`` for a row-major 9-tuple and a 3-tuple."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    x, y, z = v
    return (m0 * x + m3 * y + m6 * z, m1 * x + m4 * y + m7 * z, m2 * x + m5 * y + m8 * z)


@jitable
def reorthonormalize_f(r: Mat9) -> Mat9:
    """One step of the polar (Newton–Schulz) iteration ``R ← R (3I − RᵀR)/2``.

    For an ``R`` whose orthonormality error is ε it returns one with error O(ε²); used to stop rounding
    errors of long products of rotations from accumulating.
    """
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    # E = (I - RᵀR) / 2, symmetric
    e00 = 0.5 * (1.0 - (r0 * r0 + r3 * r3 + r6 * r6))
    e11 = 0.5 * (1.0 - (r1 * r1 + r4 * r4 + r7 * r7))
    e22 = 0.5 * (1.0 - (r2 * r2 + r5 * r5 + r8 * r8))
    e01 = -0.5 * (r0 * r1 + r3 * r4 + r6 * r7)
    e02 = -0.5 * (r0 * r2 + r3 * r5 + r6 * r8)
    e12 = -0.5 * (r1 * r2 + r4 * r5 + r7 * r8)
    return (
        r0 + r0 * e00 + r1 * e01 + r2 * e02,
        r1 + r0 * e01 + r1 * e11 + r2 * e12,
        r2 + r0 * e02 + r1 * e12 + r2 * e22,
        r3 + r3 * e00 + r4 * e01 + r5 * e02,
        r4 + r3 * e01 + r4 * e11 + r5 * e12,
        r5 + r3 * e02 + r4 * e12 + r5 * e22,
        r6 + r6 * e00 + r7 * e01 + r8 * e02,
        r7 + r6 * e01 + r7 * e11 + r8 * e12,
        r8 + r6 * e02 + r7 * e12 + r8 * e22,
    )


def solve3_f(m: Mat9, v: Vec3) -> Vec3:
    """``m⁻¹ v`` by Cramer's rule (cofactors); raises NumericalError for an exactly singular or non-finite
    ``m`` (the kernels solve well-conditioned systems near ``m I``; no condition estimate is spent here)."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    c0 = m4 * m8 - m5 * m7
    c1 = m5 * m6 - m3 * m8
    c2 = m3 * m7 - m4 * m6
    det = m0 * c0 + m1 * c1 + m2 * c2
    if det == 0.0 or not math.isfinite(det):
        raise NumericalError(f"singular or non-finite 3x3 system (det = {det!r})")
    x, y, z = v
    inv = 1.0 / det
    return (
        (c0 * x + (m2 * m7 - m1 * m8) * y + (m1 * m5 - m2 * m4) * z) * inv,
        (c1 * x + (m0 * m8 - m2 * m6) * y + (m2 * m3 - m0 * m5) * z) * inv,
        (c2 * x + (m1 * m6 - m0 * m7) * y + (m0 * m4 - m1 * m3) * z) * inv,
    )

"""Rotation-group utilities (SO(3)) shared by the estimator, the plant and the controller. Pure math.

Conventions: rotation matrices ``R`` of shape (3, 3) map body-frame vectors to the inertial frame
(``v_inertial = R @ v_body``); angular velocities are body-frame, rad/s, shape (3,). Functions accept
stacked inputs where noted (leading batch dimensions ``...``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.errors import NumericalError

Array = NDArray[np.float64]

_SMALL = 1e-4  # below this angle (rad) Taylor series replace the closed forms


def hat(v: ArrayLike) -> Array:
    """Skew-symmetric matrix ``v^×`` with ``hat(v) @ w == cross(v, w)``; shape (..., 3) → (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(m: ArrayLike) -> Array:
    """Inverse of :func:`hat` (``vex``), taking the skew part of ``m``; shape (..., 3, 3) → (..., 3)."""
    m = np.asarray(m, dtype=float)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1
    )


def exp(phi: ArrayLike) -> Array:
    """Rodrigues' formula ``exp(phi^×)``, exact to rounding at small angles; (..., 3) → (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    theta = np.sqrt(theta2)
    small = theta < _SMALL
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, np.sin(safe) / safe)
    b = np.where(
        small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, 2.0 * np.sin(0.5 * safe) ** 2 / (safe * safe)
    )
    k = hat(phi)
    k2 = k @ k
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * k2


def log(r: ArrayLike) -> Array:
    """Rotation vector ``phi`` with ``exp(phi) == r`` and ``|phi| <= pi``; stable near 0 and near pi.

    Near pi the axis is taken from the symmetric part ``(R + Rᵀ)/2 = I + (1 - cos θ) n nᵀ`` (its largest
    diagonal entry's column), with the sign fixed by the skew part. Input shape (3, 3).
    """
    r = np.asarray(r, dtype=float)
    cos_theta = np.clip((np.trace(r) - 1.0) * 0.5, -1.0, 1.0)
    theta = float(np.arccos(cos_theta))
    w = vee(r)  # = sin(theta) * n
    if theta < _SMALL:
        return w * (1.0 + theta * theta / 6.0)
    if theta < np.pi - 1e-3:
        return w * (theta / np.sin(theta))
    sym = 0.5 * (r + r.T) - cos_theta * np.eye(3)  # = (1 - cos θ) n nᵀ
    j = int(np.argmax(np.diag(sym)))
    n = sym[:, j] / np.sqrt(max(sym[j, j], 1e-300))
    n /= np.linalg.norm(n)
    if float(np.dot(n, w)) < 0.0:
        n = -n
    # refine theta with atan2 for accuracy near pi
    theta = float(np.arctan2(np.linalg.norm(w), cos_theta))
    return n * theta


def principal_angle(r: ArrayLike) -> float:
    """The angle (rad, in [0, pi]) of the rotation ``r``: ``arccos((tr r - 1)/2)``, computed robustly."""
    r = np.asarray(r, dtype=float)
    cos_theta = (np.trace(r) - 1.0) * 0.5
    sin_theta = np.linalg.norm(vee(r))
    return float(np.arctan2(sin_theta, cos_theta))


def orthonormality_error(r: ArrayLike) -> float:
    """``‖rᵀ r − I‖_F``: zero for an exact rotation."""
    r = np.asarray(r, dtype=float)
    return float(np.linalg.norm(r.T @ r - np.eye(3)))


def is_rotation(r: ArrayLike, tol: float = 1e-9) -> bool:
    """True if ``r`` is orthonormal within ``tol`` and has determinant +1."""
    r = np.asarray(r, dtype=float)
    return r.shape == (3, 3) and orthonormality_error(r) <= tol and abs(np.linalg.det(r) - 1.0) <= tol


def project(m: ArrayLike) -> Array:
    """The nearest rotation to ``m`` in the Frobenius norm (polar decomposition via SVD).

    Used to re-orthonormalise integrated attitudes; raises NumericalError for a degenerate ``m``.
    """
    m = np.asarray(m, dtype=float)
    u, s, vt = np.linalg.svd(m)
    if s[-1] <= 1e-12 * max(s[0], 1e-300):
        raise NumericalError(f"cannot project a rank-deficient matrix onto SO(3) (singular values {s})")
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def angle_between(a: ArrayLike, b: ArrayLike) -> float:
    """Angle (rad) between two rotations: the principal angle of ``a bᵀ``."""
    return principal_angle(np.asarray(a) @ np.asarray(b).T)


# --------------------------------------------------------------------------- quaternions
def quat_to_matrix(q: ArrayLike) -> Array:
    """Rotation matrix of the unit quaternion ``q = [w, x, y, z]`` (scalar first, Hamilton convention, as in
    VQF, BROAD and imufusion); shape (..., 4) → (..., 3, 3). ``q`` is normalised first; ``q`` and ``-q``
    give the same matrix. A zero or non-finite quaternion raises NumericalError."""
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0.0):
        raise NumericalError("quaternion with zero or non-finite norm has no rotation")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(r: ArrayLike) -> Array:
    """Unit quaternion ``[w, x, y, z]`` with ``w >= 0`` of the rotation ``r``; (..., 3, 3) → (..., 4).

    Shepperd's method: the largest of ``4w², 4x², 4y², 4z²`` (read off the trace and the diagonal) picks the
    formula, so there is no cancellation for any angle, 180° included.
    """
    r = np.asarray(r, dtype=float)
    r00, r11, r22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    cand = np.stack([1 + r00 + r11 + r22, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22], -1)
    k = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))  # = 2|q_k|
    d21, d02, d10 = r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]
    s21, s02, s10 = r[..., 2, 1] + r[..., 1, 2], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 0] + r[..., 0, 1]
    rows = [
        np.stack([s * s, d21, d02, d10], -1),  # from w
        np.stack([d21, s * s, s10, s02], -1),  # from x
        np.stack([d02, s10, s * s, s21], -1),  # from y
        np.stack([d10, s02, s21, s * s], -1),  # from z
    ]
    q = np.choose(k[..., None], rows) / (2.0 * s[..., None])
    q *= np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


# --------------------------------------------------------------------------- per-step kernels on floats
# The estimator steps one sample at a time; on 3-vectors and 3×3 matrices numpy's per-call overhead
# (~1 µs) dominates the arithmetic, so the per-step kernels below work on Python floats: vectors are
# 3-tuples, matrices 9-tuples in row-major order. They agree with the array functions above to rounding.

Vec3 = tuple[float, float, float]
Mat9 = tuple[float, float, float, float, float, float, float, float, float]


_C_SERIES = tuple(1.0 / math.factorial(2 * k + 3) for k in range(9))


def rodrigues_coefficients(theta2: float) -> tuple[float, float, float]:
    """``(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³)`` for ``θ² = theta2``, each to full precision.

    ``exp(φ^×) = I + a φ^× + b (φ^×)²`` and the left Jacobian ``J_l(φ) = I + b φ^× + c (φ^×)²``. Taylor
    series below 1e-4 rad; ``b`` by the half-angle form ``2 sin²(θ/2)/θ²`` and ``c`` by its series below
    1 rad (their closed forms lose up to half the digits to cancellation at small θ).
    """
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


def rotate_f(px: float, py: float, pz: float, vx: float, vy: float, vz: float) -> Vec3:
    """``exp(φ^×) v`` for ``φ = (px, py, pz)`` without forming the matrix (Rodrigues on the vector)."""
    a, b, _ = rodrigues_coefficients(px * px + py * py + pz * pz)
    cx = py * vz - pz * vy
    cy = pz * vx - px * vz
    cz = px * vy - py * vx
    return (
        vx + a * cx + b * (py * cz - pz * cy),
        vy + a * cy + b * (pz * cx - px * cz),
        vz + a * cz + b * (px * cy - py * cx),
    )


def exp_f(px: float, py: float, pz: float) -> Mat9:
    """``exp(φ^×)`` as a row-major 9-tuple (Rodrigues)."""
    a, b, _ = rodrigues_coefficients(px * px + py * py + pz * pz)
    xx, yy, zz, xy, xz, yz = px * px, py * py, pz * pz, px * py, px * pz, py * pz
    return (
        1.0 - b * (yy + zz), b * xy - a * pz, b * xz + a * py,
        b * xy + a * pz, 1.0 - b * (xx + zz), b * yz - a * px,
        b * xz - a * py, b * yz + a * px, 1.0 - b * (xx + yy),
    )  # fmt: skip


def matmul_f(p: Mat9, q: Mat9) -> Mat9:
    """``p @ q`` for row-major 9-tuples."""
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = p
    q0, q1, q2, q3, q4, q5, q6, q7, q8 = q
    return (
        p0 * q0 + p1 * q3 + p2 * q6, p0 * q1 + p1 * q4 + p2 * q7, p0 * q2 + p1 * q5 + p2 * q8,
        p3 * q0 + p4 * q3 + p5 * q6, p3 * q1 + p4 * q4 + p5 * q7, p3 * q2 + p4 * q5 + p5 * q8,
        p6 * q0 + p7 * q3 + p8 * q6, p6 * q1 + p7 * q4 + p8 * q7, p6 * q2 + p7 * q5 + p8 * q8,
    )  # fmt: skip


def apply_f(m: Mat9, v: Vec3) -> Vec3:
    """``m @ v`` for a row-major 9-tuple and a 3-tuple."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    x, y, z = v
    return (m0 * x + m1 * y + m2 * z, m3 * x + m4 * y + m5 * z, m6 * x + m7 * y + m8 * z)


def apply_transpose_f(m: Mat9, v: Vec3) -> Vec3:
    """``m.T @ v`` for a row-major 9-tuple and a 3-tuple."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    x, y, z = v
    return (m0 * x + m3 * y + m6 * z, m1 * x + m4 * y + m7 * z, m2 * x + m5 * y + m8 * z)


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

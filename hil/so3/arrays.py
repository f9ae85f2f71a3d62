"""SO(3) on numpy arrays: hat/vee, exp/log, projection, quaternions. Pure math.

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
    """Rodrigues' formula ``exp(phi^×)``, exact to rounding at small angles; (..., 3) → (..., 3, 3). A
    rotation for every finite ``phi`` (rad): one whose ``|phi|²`` overflows float64 (> 1.3e154 rad, a NaN
    matrix before) is turned by :func:`hil.so3.floats.exp_f`, the one code for such vectors."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    too_long = np.isposinf(theta2) & np.all(np.isfinite(phi), axis=-1)
    if np.any(too_long):
        from .floats import exp_f  # floats imports this module

        out = exp(np.where(too_long[..., None], 0.0, phi))
        out[too_long] = [np.reshape(exp_f(*p), (3, 3)) for p in phi[too_long].tolist()]
        return out
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


_ROTATION_TOL = 1e-6
"""The orthonormality error ``‖rᵀ r − I‖_F`` up to which :func:`log` takes a matrix for a rotation: rounding
of long products of rotations stays orders below it (the estimator and the plant re-orthonormalise), a
matrix built wrong (orthonormal to 1e-3, a reflection, zeros) lies far above it."""


def _require_rotation(r: Array, where: str) -> None:
    """NumericalError naming ``where`` unless ``r`` is a finite (3, 3) rotation to :data:`_ROTATION_TOL`.

    :func:`log` of what is no rotation answered a number without a word: the zero matrix a turn of π about
    x, a reflection ``-I`` NaN, a matrix orthonormal to 1e-3 a vector off by as much, a (4, 4) matrix
    zeros; there is no rotation vector of any of them. (A few µs: the simulated phone takes a log per
    batch of the world's steps.)"""
    if r.shape != (3, 3):
        raise NumericalError(f"{where}: need a (3, 3) rotation matrix, got shape {r.shape}")
    if not np.isfinite(r).all():
        raise NumericalError(f"{where}: not a rotation: non-finite entries {r.tolist()}")
    error = float(np.linalg.norm(r.T @ r - _EYE3))
    if not error <= _ROTATION_TOL:
        raise NumericalError(
            f"{where}: not a rotation: orthonormality error ‖rᵀr − I‖ = {error:.3g} (tolerance "
            f"{_ROTATION_TOL:g}) of {r.tolist()}"
        )
    (a, b, c), (d, e, f), (g, h, i) = r.tolist()
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)  # ±1 to the tolerance
    if det <= 0.0:
        raise NumericalError(f"{where}: not a rotation: determinant {det:.6g} (a reflection) of {r.tolist()}")


_EYE3 = np.eye(3)


def log(r: ArrayLike) -> Array:
    """Rotation vector ``phi`` with ``exp(phi) == r`` and ``|phi| <= pi``; stable near 0 and near pi.

    Near pi the axis is taken from the symmetric part ``(R + Rᵀ)/2 = I + (1 - cos θ) n nᵀ`` (its largest
    diagonal entry's column), with the sign fixed by the skew part. Input shape (3, 3), a rotation to
    :data:`_ROTATION_TOL`; anything else (non-finite, not orthonormal, a reflection, another shape) raises
    NumericalError naming it.
    """
    r = np.asarray(r, dtype=float)
    _require_rotation(r, "so3.log")
    cos_theta = float(np.clip((np.trace(r) - 1.0) * 0.5, -1.0, 1.0))
    w = vee(r)  # = sin(theta) * n
    sin_theta = float(np.linalg.norm(w))
    # atan2, not arccos: arccos loses digits as θ nears π (its slope 1/sin θ), and θ/sin θ magnified them
    # to 4e-10 rad at 1.2 mrad from π; θ/|w| keeps θ and sin θ consistent
    theta = float(np.arctan2(sin_theta, cos_theta))
    if theta < _SMALL:
        return w * (1.0 + theta * theta / 6.0)
    if theta < np.pi - 1e-3:
        return w * (theta / sin_theta)
    sym = 0.5 * (r + r.T) - cos_theta * np.eye(3)  # = (1 - cos θ) n nᵀ
    j = int(np.argmax(np.diag(sym)))
    n = sym[:, j] / np.sqrt(max(sym[j, j], 1e-300))
    n /= np.linalg.norm(n)
    if float(np.dot(n, w)) < 0.0:
        n = -n
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
    if not np.all(np.isfinite(m)):  # numpy's SVD raised a bare LinAlgError ("did not converge")
        raise NumericalError(f"cannot project a non-finite matrix onto SO(3): {m.tolist()}")
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
    VQF, BROAD and imufusion); shape (..., 4) → (..., 3, 3). ``q`` is normalised first, at any scale;
    ``q`` and ``-q`` give the same matrix. A zero or non-finite quaternion raises NumericalError naming it.

    One whose largest component lies outside [1e-100, 1e100] is first divided by that component: its
    squares underflowed or overflowed the norm, so a quaternion of norm 1e-300 or 1e300 was refused as
    "zero or non-finite", and one of 1e-160 was normalised by a norm of denormals, 1e-4 off, into a
    matrix that was no rotation."""
    q = np.asarray(q, dtype=float)
    largest = np.max(np.abs(q), axis=-1, keepdims=True)
    bad = ~np.isfinite(largest[..., 0]) | (largest[..., 0] == 0.0)
    if np.any(bad):
        first = tuple(int(i) for i in np.argwhere(bad)[0]) if bad.ndim else ()
        raise NumericalError(
            f"quaternion {f'at index {list(first)} ' if first else ''}{q[first].tolist()} is zero or not "
            "finite: it has no rotation"
        )
    far_scale = (largest < 1e-100) | (largest > 1e100)
    if np.any(far_scale):
        q = np.where(far_scale, q / largest, q)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
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


def euler_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Array:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (3, 3), body → inertial (the aerospace yaw-pitch-roll sequence), from
    angles in degrees. An angle that is no finite number raises NumericalError naming it: inf raised a bare
    ValueError ("math domain error"), a string a bare TypeError, and NaN gave a matrix of NaN."""
    r, p, y = (
        math.radians(_finite_angle(a, f"so3.euler_zyx.{name}"))
        for a, name in ((roll_deg, "roll_deg"), (pitch_deg, "pitch_deg"), (yaw_deg, "yaw_deg"))
    )
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _finite_angle(value: object, where: str) -> float:
    """``value`` as a finite float (an angle); NumericalError naming ``where`` for anything else."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise NumericalError(f"{where} = {value!r} is not a number")
    try:
        angle = float(value)
    except OverflowError:  # an int beyond float's range (10**400)
        angle = math.inf
    if not math.isfinite(angle):
        raise NumericalError(f"{where} = {angle!r} is not a finite angle")
    return angle

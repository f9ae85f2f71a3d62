"""Attitudes as quaternions for many steps at once, compiled: :func:`hil.so3.matrix_to_quat` (numpy, the
reference the tests compare it with) costs ~0.5 µs per matrix in its dozen array passes, which a replay of a
long log pays on every estimate it writes; this kernel does the same arithmetic in one pass."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.jit import kernel

Array = NDArray[np.float64]


def quats_of(R: Array) -> Array:
    """Unit quaternions ``[w, x, y, z]`` with ``w >= 0`` (N, 4) of the rotations ``R`` (N, 3, 3), as
    :func:`hil.so3.matrix_to_quat` gives them (Shepperd's method, to rounding)."""
    R = np.ascontiguousarray(R, dtype=float).reshape(-1, 3, 3)
    out = np.empty((R.shape[0], 4))
    _quats(R, out)
    return out


@kernel
def _quats(R: Array, out: Array) -> None:
    for n in range(R.shape[0]):
        r = R[n]
        c0 = 1.0 + r[0, 0] + r[1, 1] + r[2, 2]
        c1 = 1.0 + r[0, 0] - r[1, 1] - r[2, 2]
        c2 = 1.0 - r[0, 0] + r[1, 1] - r[2, 2]
        c3 = 1.0 - r[0, 0] - r[1, 1] + r[2, 2]
        k, big = 0, c0  # the largest candidate picks the formula (first of equals, as argmax)
        if c1 > big:
            k, big = 1, c1
        if c2 > big:
            k, big = 2, c2
        if c3 > big:
            k, big = 3, c3
        s = math.sqrt(max(big, 1e-300))  # = 2|q_k|
        d21, d02, d10 = r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]
        s21, s02, s10 = r[2, 1] + r[1, 2], r[0, 2] + r[2, 0], r[1, 0] + r[0, 1]
        ss = s * s
        if k == 0:
            w, x, y, z = ss, d21, d02, d10
        elif k == 1:
            w, x, y, z = d21, ss, s10, s02
        elif k == 2:
            w, x, y, z = d02, s10, ss, s21
        else:
            w, x, y, z = d10, s02, s21, ss
        d = 2.0 * s
        w, x, y, z = w / d, x / d, y / d, z / d
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        out[n, 0], out[n, 1], out[n, 2], out[n, 3] = w / norm, x / norm, y / norm, z / norm

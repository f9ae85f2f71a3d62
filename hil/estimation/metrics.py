"""Attitude-estimation error metrics, as the BROAD benchmark (Laidig et al.) defines them, plus the paper's.

For an estimate ``q̂`` and reference ``q`` (unit quaternions ``[w, x, y, z]``, body → ENU) the error is
expressed in the earth frame, ``e = q̂ ⊗ q⁻¹`` (the rotation taking the true attitude to the estimated
one, seen from the world). Then, in radians:

- total error       ``2 acos |e_w|``           (the principal angle of ``Q = R̂ Rᵀ``, as in the paper)
- heading error     ``2 atan |e_z / e_w|``     (the part about the vertical axis)
- inclination error ``2 acos √(e_w² + e_z²)``  (the rest: tilt of the estimated vertical)

and RMSE of each over the evaluated samples, in degrees. (The paper writes ``Q = R R̂ᵀ``; its principal
angle is the same as that of ``R̂ Rᵀ``.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.sensors import MAX_PAUSE_S

Array = NDArray[np.float64]


def quat_multiply(a: ArrayLike, b: ArrayLike) -> Array:
    """Hamilton product ``a ⊗ b`` of quaternions ``[w, x, y, z]``, row-wise; shapes (..., 4)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def error_quat_earth(q_est: ArrayLike, q_ref: ArrayLike) -> Array:
    """``q̂ ⊗ q⁻¹``, normalised, (N, 4)."""
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    q_est = q_est / np.linalg.norm(q_est, axis=-1, keepdims=True)
    q_ref = q_ref / np.linalg.norm(q_ref, axis=-1, keepdims=True)
    e = quat_multiply(q_est, q_ref * np.array([1.0, -1.0, -1.0, -1.0]))
    return e / np.linalg.norm(e, axis=-1, keepdims=True)


@dataclass(frozen=True)
class AttitudeErrors:
    """Per-sample errors in degrees, each (N,)."""

    total: Array
    heading: Array
    inclination: Array

    @classmethod
    def from_quats(cls, q_est: ArrayLike, q_ref: ArrayLike) -> AttitudeErrors:
        e = error_quat_earth(q_est, q_ref)
        w, z = np.abs(e[:, 0]), np.abs(e[:, 3])
        total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
        heading = 2.0 * np.arctan2(z, w)
        incl = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
        return cls(np.degrees(total), np.degrees(heading), np.degrees(incl))

    @classmethod
    def from_matrices(cls, r_est: ArrayLike, r_ref: ArrayLike) -> AttitudeErrors:
        """From rotation matrices (N, 3, 3), body → ENU."""
        return cls.from_quats(so3.matrix_to_quat(r_est), so3.matrix_to_quat(r_ref))

    def rmse(self, mask: ArrayLike | None = None) -> Rmse:
        """RMSE over the samples in ``mask`` (default all), NaNs (no estimate or no truth) left out."""
        sel = np.ones(self.total.shape, bool) if mask is None else np.asarray(mask, bool)
        return Rmse(
            _rms(self.total[sel]), _rms(self.heading[sel]), _rms(self.inclination[sel]), int(sel.sum())
        )


@dataclass(frozen=True)
class Rmse:
    """Root-mean-square errors in degrees over ``n`` samples."""

    total: float
    heading: float
    inclination: float
    n: int

    def __str__(self) -> str:
        return f"{self.total:.2f} / {self.heading:.2f} / {self.inclination:.2f} deg (total / heading / incl.)"


def _rms(x: Array) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def resample_quats(t: ArrayLike, q: ArrayLike, at: ArrayLike) -> Array:
    """Quaternions ``q`` (N, 4) at times ``t`` (N,, increasing) interpolated to ``at`` (M,): normalised
    linear interpolation along the shorter arc between the neighbours; NaN outside ``[t[0], t[-1]]``."""
    t, q, at = np.asarray(t, float), np.asarray(q, float), np.asarray(at, float)
    i = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    f = ((at - t[i]) / (t[i + 1] - t[i]))[:, None]
    a, b = q[i], q[i + 1]
    b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    out = (1.0 - f) * a + f * b
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    out[(at < t[0]) | (at > t[-1])] = np.nan
    return out


def rate_error(omega_est: ArrayLike, omega_true: ArrayLike) -> Array:
    """Norm of the angular-velocity estimation error (rad/s), (N,)."""
    return np.linalg.norm(np.asarray(omega_est, float) - np.asarray(omega_true, float), axis=-1)


def settling_time(t: ArrayLike, error: ArrayLike, bound: float) -> float:
    """The first time after which ``error`` stays at or below ``bound`` (inf if it never settles)."""
    t, error = np.asarray(t, float), np.asarray(error, float)
    above = np.flatnonzero(~(error <= bound))
    if above.size == 0:
        return float(t[0])
    if above[-1] == len(t) - 1:
        return float("inf")
    return float(t[above[-1] + 1])


def truth_rates(t: ArrayLike, r: ArrayLike) -> tuple[Array, Array]:
    """Body rates (rad/s) implied by a truth attitude series (N, 3, 3), at the N−1 midpoints:
    ``log(R_kᵀ R_{k+1}) / Δt``. NaN (no rate known) for a pair with a NaN frame (occlusion), and for a pair
    whose Δt is not in (0, :data:`~hil.estimation.sensors.MAX_PAUSE_S`]: a duplicated stamp gave an
    infinite rate, a stamp going back the rate reversed, and a gap in the truth the mean of a rotation
    ``log`` folds into ±π — none of them the body's rate."""
    t, r = np.asarray(t, float), np.asarray(r, float)
    mid = 0.5 * (t[1:] + t[:-1])
    dt = np.diff(t)
    rel = np.einsum("nji,njk->nik", r[:-1], r[1:])
    omega = np.full((len(mid), 3), np.nan)
    known = np.all(np.isfinite(rel.reshape(len(mid), 9)), axis=1) & (dt > 0.0) & (dt <= MAX_PAUSE_S)
    for i in np.flatnonzero(known):
        omega[i] = so3.log(rel[i]) / dt[i]
    return mid, omega


@dataclass(frozen=True)
class TruthComparison:
    """Estimates against ground truth, at the truth's timestamps ``t``: attitude ``errors`` (deg), the
    benchmark's ``mask`` (evaluated, finite), their ``rmse``; and the rate error ``Ω − Ω̂`` (rad/s) at the
    truth's midpoints ``rate_t`` (NaN where either end is not in ``mask``, or :func:`truth_rates` knows
    no rate) with its RMS norm ``rate_rmse`` (rad/s)."""

    t: Array
    errors: AttitudeErrors
    mask: NDArray[np.bool_]
    rmse: Rmse
    rate_t: Array
    rate_error: Array
    rate_rmse: float


def compare_to_truth(
    truth_t: ArrayLike,
    truth_r: ArrayLike,
    evaluate: ArrayLike | None,
    t_est: ArrayLike,
    q_est: ArrayLike,
    omega_est: ArrayLike | None = None,
) -> TruthComparison:
    """Interpolate estimates (quaternions (N, 4) body → ENU, optional rates (N, 3)) at times ``t_est`` to
    the truth (times (M,), rotations (M, 3, 3), NaN frames allowed) and score them."""
    truth_t, truth_r = np.asarray(truth_t, float), np.asarray(truth_r, float)
    t_est = np.asarray(t_est, float)
    finite = np.all(np.isfinite(truth_r.reshape(len(truth_t), 9)), axis=1)
    q_ref = np.full((len(truth_t), 4), np.nan)
    q_ref[finite] = so3.matrix_to_quat(truth_r[finite])
    q_at = resample_quats(t_est, q_est, truth_t)
    errors = AttitudeErrors.from_quats(q_at, q_ref)
    evaluated = np.ones(len(truth_t), bool) if evaluate is None else np.asarray(evaluate, bool)
    mask = evaluated & finite & np.all(np.isfinite(q_at), axis=1)
    mid, w_true = truth_rates(truth_t, truth_r)
    rate_error = np.full_like(w_true, np.nan)
    if omega_est is not None:
        w = np.asarray(omega_est, float)
        w_at = np.column_stack([np.interp(mid, t_est, w[:, i], left=np.nan, right=np.nan) for i in range(3)])
        rate_error = w_true - w_at
        # scored between two scored truth samples only, as the attitude is: across a part not replayed
        # (a gap) the rate "estimate" is two parts' ends joined by interpolation (a 20 s gap in the 4 s
        # fixture raised its RMS from 0.007 to 0.57 rad/s), and outside ``evaluate`` nothing is scored
        rate_error[~(mask[:-1] & mask[1:])] = np.nan
    norm = np.linalg.norm(rate_error, axis=1)
    return TruthComparison(truth_t, errors, mask, errors.rmse(mask), mid, rate_error, _rms(norm))

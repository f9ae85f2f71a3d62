"""The numpy reference of the compiled steering law (:mod:`hil.control.steering`): the weighted
pseudo-inverse with its damped least squares, the rotor-speed re-solve, the null motion and the limit
scaling on numpy arrays with a batch axis, written from the equations (the damping's smallest eigenvalue
from ``numpy.linalg.eigvalsh``). The tests compare the kernels with it to rounding; nothing runs it
at run time. Pure math."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from hil.control.steering import TORQUE_SCALED_ABOVE, Array, Saturation, SteeringOutput, VscmgSteering


def delta_gradient(steer: VscmgSteering, gimbal_angle: ArrayLike, rotor_speed: ArrayLike) -> Array:
    """``∂δ/∂γ`` (B, n): ``2 (∂d₁ᵢ)ᵀ adj(A) d₁ᵢ / h̄⁶`` with ``A = D₁D₁ᵀ`` and ``∂d₁ᵢ/∂γᵢ = −I_Ws Ω sᵢ``."""
    s, t = steer.axes(np.atleast_2d(gimbal_angle))
    w = np.atleast_2d(np.asarray(rotor_speed, dtype=float))
    d1 = (steer.I_ws * w)[..., None] * t
    dd1 = -(steer.I_ws * w)[..., None] * s
    A = np.einsum("bni,bnj->bij", d1, d1)
    return 2.0 * np.einsum("bni,bij,bnj->bn", dd1, adjugate(A), d1) / steer.h_bar**6


def solve(
    steer: VscmgSteering, torque: ArrayLike, gimbal_angle: ArrayLike, rotor_speed: ArrayLike, dt: float
) -> SteeringOutput:
    """:meth:`VscmgSteering.solve` on numpy arrays (B rows at once). Inputs with no finite command get
    none, flagged NOT_FINITE (the kernel's module docstring): numpy's warnings on their NaN are silenced."""
    with np.errstate(invalid="ignore", over="ignore"):
        return _solve(steer, torque, gimbal_angle, rotor_speed, dt)


def _solve(
    steer: VscmgSteering, torque: ArrayLike, gimbal_angle: ArrayLike, rotor_speed: ArrayLike, dt: float
) -> SteeringOutput:
    """:func:`solve` within its ``np.errstate``."""
    L = np.atleast_2d(np.asarray(torque, dtype=float))
    big = np.max(np.abs(L), axis=1, keepdims=True)  # a larger torque is solved scaled to the threshold
    L = np.where(big > TORQUE_SCALED_ABOVE, L * (TORQUE_SCALED_ABOVE / np.where(big > 0, big, 1.0)), L)
    gam = np.atleast_2d(np.asarray(gimbal_angle, dtype=float))
    w = np.atleast_2d(np.asarray(rotor_speed, dtype=float))
    lim, p = steer.params.limits, steer.p
    n = steer.g.shape[0]
    D0, D1 = steer.jacobians(gam, w)
    Q = np.concatenate([D0, D1], axis=-1)
    delta = np.linalg.det(D1 @ np.swapaxes(D1, -1, -2)) / steer.h_bar**6
    scale2 = steer.params.nominal_rotor_speed**2
    ws = np.repeat((p.wheel_weight * scale2 * np.exp(-p.mu * delta))[:, None], n, axis=1)
    sat = np.zeros(L.shape[0], dtype=np.int64)
    eta, damped = _weighted(steer, Q, ws, -L)
    # rotors about to leave their speed range lose wheel mode (one re-solve)
    ahead = w + eta[:, :n] * dt
    out = ((ahead > lim.max_rotor_speed) & (eta[:, :n] > 0)) | (
        (ahead < lim.min_rotor_speed) & (eta[:, :n] < 0)
    )
    if out.any():
        ws = np.where(out, 0.0, ws)
        again, damped_again = _weighted(steer, Q, ws, -L)
        redo: Array = np.asarray(out.any(axis=1))
        eta = np.where(redo[:, None], again, eta)
        damped = np.where(redo, damped_again, damped)
        sat |= np.where(redo, int(Saturation.ROTOR_SPEED), 0)
    sat |= np.where(damped > 0.0, int(Saturation.DAMPED), 0)
    if p.null_gain > 0:
        nominal = steer.params.nominal_rotor_speed
        d = np.concatenate(
            [-p.speed_gain * (w - nominal) / nominal**2, delta_gradient(steer, gam, w)], axis=1
        )
        wd = np.concatenate([ws, np.full_like(ws, p.gimbal_weight)], axis=1) * d
        eta += p.null_gain * (wd - _weighted(steer, Q, ws, np.einsum("bij,bj->bi", Q, wd))[0])
    # one scale factor for every limit
    g_ratio = np.max(np.abs(eta[:, n:]), axis=1) / lim.max_gimbal_rate
    a_ratio = np.max(np.abs(eta[:, :n]), axis=1) / lim.max_rotor_accel
    scale = 1.0 / np.maximum(1.0, np.maximum(g_ratio, a_ratio))
    sat |= np.where(g_ratio > 1.0, int(Saturation.GIMBAL_RATE), 0)
    sat |= np.where(a_ratio > 1.0, int(Saturation.ROTOR_ACCEL), 0)
    finite = np.all(np.isfinite(eta), axis=1)  # else no finite command: none
    scale = np.where(finite, scale, 0.0)
    sat = np.where(finite, sat, int(Saturation.NOT_FINITE))
    eta = np.where(finite[:, None], eta * scale[:, None], 0.0)
    delivered = np.where(finite[:, None], -np.einsum("bij,bj->bi", Q, eta), 0.0)
    return SteeringOutput(eta[:, n:], eta[:, :n], delivered, delta, ws, scale, sat)


def _weighted(steer: VscmgSteering, Q: Array, ws: Array, rhs: Array) -> tuple[Array, Array]:
    """``W Qᵀ (Q W Qᵀ + λ² I)⁻¹ rhs`` (B, 2n) and λ² (B,): ``λ² = damping h̄² (1 − σ/ε)²`` where the
    smallest eigenvalue σ of Q W Qᵀ is below ``ε = singular_eps h̄²``, else 0."""
    W = np.concatenate([ws, np.full_like(ws, steer.p.gimbal_weight)], axis=1)
    QW = Q * W[:, None, :]
    M = QW @ np.swapaxes(Q, -1, -2)
    finite = np.all(np.isfinite(M), axis=(1, 2))  # NaN in: NaN out (the eigensolver would raise)
    M = np.where(finite[:, None, None], M, np.eye(3))
    sigma = np.linalg.eigvalsh(M)[:, 0]
    h2 = steer.h_bar**2
    eps = steer.p.singular_eps * h2
    damp = np.where(sigma < eps, steer.p.damping * h2 * (1.0 - np.maximum(sigma, 0.0) / eps) ** 2, 0.0)
    lam = np.linalg.solve(M + damp[:, None, None] * np.eye(3), rhs[..., None])
    lam[~finite] = np.nan
    return (np.swapaxes(QW, -1, -2) @ lam)[..., 0], damp


def adjugate(A: Array) -> Array:
    """Adjugate of (B, 3, 3) matrices (= det(A) A⁻¹ where A is invertible), by cofactors."""
    c = np.empty_like(A)
    for i in range(3):
        for j in range(3):
            r = [k for k in range(3) if k != j]
            s = [k for k in range(3) if k != i]
            minor = A[:, r][:, :, s]
            c[:, i, j] = (-1) ** (i + j) * (minor[:, 0, 0] * minor[:, 1, 1] - minor[:, 0, 1] * minor[:, 1, 0])
    return c

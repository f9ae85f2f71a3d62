"""The attitude filter's chain as compiled kernels: one call per merged step (:func:`step`) or per batch
of steps (:func:`run`), the same code. Pure math, no I/O.

A step: the gyro bias is removed; the three signals go through the pre-filter
(:func:`hil.estimation.prefilter.signal_step`); the magnetometer through the disturbance gate
(:func:`~hil.estimation.prefilter.gate_step`, flagging :attr:`StepFlag.MAG_DISTURBED`) and, if asked, is
reduced to its part perpendicular to the measured gravity (heading only); an estimator waiting for a
measured initial attitude restarts from Wahba's solution (:func:`wahba`) at the first step where both
directions are usable; then the estimator steps (:func:`hil.estimation.variational.step`).
:class:`hil.estimation.filter.AttitudeFilter` holds the arrays and makes the calls.

Arrays (float64; slots are the constants below) — besides the estimator's own (``ep``, ``es``,
:mod:`hil.estimation.variational`):

- chain parameters ``cp`` (:data:`CP_SIZE`): horizontal-magnetometer flag, gate flag, ω0 for a measured
  restart (3), then the pre-filter's parameters (``SP_SIZE``) and the gate's (``GP_SIZE``);
- chain state ``cs`` (:data:`CS_SIZE`): the gyro bias removed (3, rad/s), waiting-for-a-measured-attitude
  flag, the last step's time (s), this step's signals (9: gyr, acc, mag), then the pre-filter's state
  (``SS_SIZE``) and the gate's (``GS_SIZE``).

A later stage (online gyro-bias estimation, magnetic disturbance handling, adaptive accelerometer trust)
appends its slots to these layouts and its code to :func:`step`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation import prefilter as pf
from hil.estimation import variational as v
from hil.estimation.prefilter import gate_step, signal_step
from hil.estimation.sensors import StepFlag
from hil.jit import kernel

Array = NDArray[np.float64]

CP_HORIZONTAL = 0  # 1: the magnetometer's part perpendicular to gravity only
CP_GATE = 1  # 1: the magnetic gate is on
CP_OMEGA0 = 2  # ω0 (3) rad/s for the measured restart
CP_SIGNAL = 5  # the pre-filter's parameters (pf.SP_SIZE)
CP_GATE_PARAMS = CP_SIGNAL + pf.SP_SIZE  # the gate's parameters (pf.GP_SIZE)
CP_SIZE = CP_GATE_PARAMS + pf.GP_SIZE

CS_BIAS = 0  # gyro bias (3) rad/s, subtracted first
CS_AWAITING = 3  # 1: restart from Wahba's solution at the first step with both directions usable
CS_T = 4  # the last step's time (s)
CS_IO = 5  # this step's gyr, acc, mag (9)
CS_SIGNAL = CS_IO + 9  # the pre-filter's state (pf.SS_SIZE)
CS_GATE = CS_SIGNAL + pf.SS_SIZE  # the gate's state (pf.GS_SIZE)
CS_SIZE = CS_GATE + pf.GS_SIZE

BAD_STEP = v.BAD_STEP
_MAG_DISTURBED = int(StepFlag.MAG_DISTURBED)
_NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)
_GYR_STALE = int(StepFlag.GYR_STALE)
_ACC_STALE = int(StepFlag.ACC_STALE)
_MAG_STALE = int(StepFlag.MAG_STALE)


def pack_params(
    signal: Array, gate: Array | None, horizontal: bool, omega_err0: tuple[float, float, float]
) -> Array:
    """The chain parameters ``cp``: pre-filter parameters ``signal`` (``pf.pack_signal_params``), gate
    parameters (``pf.pack_gate_params``, None: no gate), horizontal magnetometer, ω0 (rad/s)."""
    cp = np.zeros(CP_SIZE)
    cp[CP_HORIZONTAL] = 1.0 if horizontal else 0.0
    cp[CP_OMEGA0 : CP_OMEGA0 + 3] = omega_err0
    cp[CP_SIGNAL : CP_SIGNAL + pf.SP_SIZE] = signal
    if gate is not None:
        cp[CP_GATE] = 1.0
        cp[CP_GATE_PARAMS : CP_GATE_PARAMS + pf.GP_SIZE] = gate
    return cp


def new_state(bias: ArrayLike, awaiting: bool) -> Array:
    """A chain state ``cs`` before the first step: ``bias`` (3,) rad/s, waiting for a measured attitude."""
    cs = np.zeros(CS_SIZE)
    cs[CS_BIAS : CS_BIAS + 3] = np.asarray(bias, dtype=float).reshape(3)
    cs[CS_AWAITING] = 1.0 if awaiting else 0.0
    cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE] = pf.new_signal_state()
    return cs


@kernel
def wahba(ep, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """The attitude minimising U⁰ for one pair of usable, non-parallel measurements (Wahba's problem; its
    numpy reference is :func:`hil.estimation.params.wahba`, by SVD): a row-major 9-tuple, body → inertial.

    The optimum is the orthogonal polar factor of ``B = E W Uᵀ`` (its SVD ``P Σ Qᵀ`` gives ``P Qᵀ``; no
    sign correction is needed: E and U are right-handed and W positive definite, so ``det B > 0``). It is
    found by Newton's iteration ``X ← (γX + (γX)⁻ᵀ)/2`` with determinant scaling ``γ = |det X|^(-1/3)``
    (Higham), which converges quadratically to rounding in a handful of steps — and compiles in a fraction
    of the time numba's LAPACK SVD takes."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    u1x, u1y, u1z = ax / na, ay / na, az / na
    u2x, u2y, u2z = mx / nm, my / nm, mz / nm
    cx, cy, cz = u1y * u2z - u1z * u2y, u1z * u2x - u1x * u2z, u1x * u2y - u1y * u2x
    nc = math.sqrt(cx * cx + cy * cy + cz * cz)
    u = (u1x, u2x, cx / nc, u1y, u2y, cy / nc, u1z, u2z, cz / nc)  # row-major; columns u1, u2, u1×u2
    e = ep[v.P_E : v.P_E + 9]
    w = ep[v.P_W : v.P_W + 9]
    ew = [0.0] * 9
    for i in range(3):
        for j in range(3):
            ew[3 * i + j] = e[3 * i] * w[j] + e[3 * i + 1] * w[3 + j] + e[3 * i + 2] * w[6 + j]
    x = [0.0] * 9  # B = (E W) Uᵀ
    for i in range(3):
        for j in range(3):
            x[3 * i + j] = ew[3 * i] * u[3 * j] + ew[3 * i + 1] * u[3 * j + 1] + ew[3 * i + 2] * u[3 * j + 2]
    for it in range(60):
        c = adjugate_t(x)  # cofactors: X⁻ᵀ = cof(X) / det X
        det = x[0] * c[0] + x[1] * c[1] + x[2] * c[2]
        g = abs(det) ** (-1.0 / 3.0) if it < 6 else 1.0
        change = 0.0
        for i in range(9):
            y = 0.5 * (g * x[i] + c[i] / (g * det))
            change = max(change, abs(y - x[i]))
            x[i] = y
        if change <= 1e-15:
            break
    return (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8])


@kernel
def adjugate_t(x):  # type: ignore[no-untyped-def]
    """The cofactor matrix of a row-major 3×3 ``x`` (the transposed adjugate: ``X⁻ᵀ = cof X / det X``)."""
    return [
        x[4] * x[8] - x[5] * x[7], x[5] * x[6] - x[3] * x[8], x[3] * x[7] - x[4] * x[6],
        x[2] * x[7] - x[1] * x[8], x[0] * x[8] - x[2] * x[6], x[1] * x[6] - x[0] * x[7],
        x[1] * x[5] - x[2] * x[4], x[2] * x[3] - x[0] * x[5], x[0] * x[4] - x[1] * x[3],
    ]  # fmt: skip


@kernel
def both_usable(ep, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """Both directions finite, non-zero and further apart than ``min_direction_angle_deg``."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    if not (math.isfinite(na) and math.isfinite(nm) and na > 0.0 and nm > 0.0):
        return False
    cx, cy, cz = ay * mz - az * my, az * mx - ax * mz, ax * my - ay * mx
    return math.sqrt(cx * cx + cy * cy + cz * cz) / (na * nm) >= ep[v.P_MIN_SIN]


@kernel
def step(cp, cs, ep, es, t, h, gx, gy, gz, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """One merged step at time ``t`` (s), ``h`` s after the previous one (ignored on the first): raw
    gyr (rad/s), acc, mag (NaN: not usable). Returns the estimator step's flags, with
    :attr:`StepFlag.MAG_DISTURBED` when the gate rejected the magnetometer, ``| newton_updates <<
    ITER_SHIFT``; or :data:`BAD_STEP` (nothing changed) for a step after the first whose ``h`` is not a
    positive number."""
    ss = cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE]
    if ss[pf.SS_N] > 0.0 and not (h > 0.0 and math.isfinite(h)):
        return BAD_STEP
    io = cs[CS_IO : CS_IO + 9]
    io[0], io[1], io[2] = gx - cs[CS_BIAS], gy - cs[CS_BIAS + 1], gz - cs[CS_BIAS + 2]
    io[3], io[4], io[5] = ax, ay, az
    io[6], io[7], io[8] = mx, my, mz
    signal_step(cp[CP_SIGNAL : CP_SIGNAL + pf.SP_SIZE], ss, h, io)
    ax, ay, az, mx, my, mz = io[3], io[4], io[5], io[6], io[7], io[8]
    flags = 0
    if cp[CP_GATE] != 0.0 and math.isfinite(mx + my + mz):
        gp = cp[CP_GATE_PARAMS : CP_GATE_PARAMS + pf.GP_SIZE]
        if not gate_step(gp, cs[CS_GATE : CS_GATE + pf.GS_SIZE], h, ax, ay, az, mx, my, mz):
            mx = my = mz = math.nan
            flags |= _MAG_DISTURBED
    if cp[CP_HORIZONTAL] != 0.0:
        n2 = ax * ax + ay * ay + az * az
        if n2 > 0.0 and math.isfinite(n2) and math.isfinite(mx + my + mz):
            k = (mx * ax + my * ay + mz * az) / n2
            mx, my, mz = mx - k * ax, my - k * ay, mz - k * az
        else:
            mx = my = mz = math.nan
    if cs[CS_AWAITING] != 0.0 and both_usable(ep, ax, ay, az, mx, my, mz):
        cs[CS_AWAITING] = 0.0  # restart the estimator from the measured attitude, counters from zero
        r = wahba(ep, ax, ay, az, mx, my, mz)
        es[:] = 0.0
        for i in range(9):
            es[v.S_R + i] = r[i]
        for i in range(3):
            es[v.S_OMEGA + i] = cp[CP_OMEGA0 + i]
    code = v.step(ep, es, h, io[0], io[1], io[2], ax, ay, az, mx, my, mz)
    if code < 0:  # an estimator stepped outside this chain: its h is not this one's
        return code
    es[v.S_T] = t
    cs[CS_T] = t
    return code | flags


@kernel
def run(cp, cs, ep, es, t, flags_in, gyr, acc, mag, out_r, out_omega, out_w, out_flags, out_iters):  # type: ignore[no-untyped-def]
    """:func:`step` over N merged steps at times ``t`` (N,) s, strictly increasing and after the chain's
    last step (the caller checks); ``gyr``, ``acc``, ``mag`` (N, 3), a sensor flagged stale in
    ``flags_in`` (N,) being not usable. Writes R̂ (N, 3, 3), Ω̂ and ω (N, 3), flags (``flags_in`` | the
    step's) and Newton updates (N,). Returns the number of steps taken: fewer than N after a bad step or,
    with the "raise" failure policy, after the first step whose Newton solve failed."""
    n = t.shape[0]
    stop = ep[v.P_RAISE] != 0.0
    nan = math.nan
    for i in range(n):
        fi = flags_in[i]
        gx, gy, gz = (nan, nan, nan) if fi & _GYR_STALE else (gyr[i, 0], gyr[i, 1], gyr[i, 2])
        ax, ay, az = (nan, nan, nan) if fi & _ACC_STALE else (acc[i, 0], acc[i, 1], acc[i, 2])
        mx, my, mz = (nan, nan, nan) if fi & _MAG_STALE else (mag[i, 0], mag[i, 1], mag[i, 2])
        h = t[i] - cs[CS_T] if cs[CS_SIGNAL + pf.SS_N] > 0.0 else 0.0
        code = step(cp, cs, ep, es, t[i], h, gx, gy, gz, ax, ay, az, mx, my, mz)
        if code < 0:
            return i
        v.write_row(es, i, out_r, out_omega, out_w)
        out_flags[i] = fi | (code & v.FLAG_BITS)
        out_iters[i] = code >> v.ITER_SHIFT
        if stop and code & _NEWTON_FAILED:
            return i + 1
    return n

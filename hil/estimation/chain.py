"""The attitude filter's chain as compiled kernels: one call per merged step (:func:`step`) or per batch
of steps (:func:`run`), the same code. Pure math, no I/O.

A step: the gyro, less the bias estimate b̂, and the accelerometer and magnetometer go through the
pre-filter (:func:`hil.estimation.prefilter.signal_step`; the accelerometer's cut-off scaled by its trust);
rest detection and the accelerometer's trust are updated (:func:`hil.estimation.motion.motion_step`), and
at rest b̂ moves toward the low-passed gyro (:attr:`StepFlag.REST`); the magnetometer goes through the
disturbance handling (:func:`hil.estimation.magnetic.mag_step`, :attr:`StepFlag.MAG_DISTURBED` while it
is left out) and, if asked, is reduced to its part perpendicular to the measured gravity (heading only),
or is not used at all (6-axis); an estimator waiting for a measured initial attitude restarts from Wahba's
solution (:func:`wahba`) at the first step where both directions are usable — from gravity alone
(:func:`tilt`) while there is no field yet; then the estimator steps (:func:`hil.estimation.variational.
step`, which updates b̂ by the variational law). :class:`hil.estimation.filter.AttitudeFilter` holds the
arrays and makes the calls.

Arrays (float64; slots are the constants below) — besides the estimator's own (``ep``, ``es``,
:mod:`hil.estimation.variational`, whose state holds b̂):

- chain parameters ``cp`` (:data:`CP_SIZE`): the magnetometer's use (``MAG_*``), disturbance-handling
  flag, ω0 for a measured restart (3), the pre-filter's parameters (``SP_SIZE``), the magnetic handling's
  (``GP_SIZE``), the motion flag and rest detection's and accelerometer trust's (``MP_SIZE``);
- chain state ``cs`` (:data:`CS_SIZE`): the initial gyro bias estimate (3, rad/s), where the measured
  initial attitude stands (``AWAIT_*``), the last step's time (s), this step's signals (9: gyr, acc, mag),
  then the pre-filter's state (``SS_SIZE``), the magnetic handling's (``GS_SIZE``) and the motion state
  (``MS_SIZE``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation import magnetic as mg
from hil.estimation import motion as mo
from hil.estimation import prefilter as pf
from hil.estimation import variational as v
from hil.estimation.magnetic import mag_step
from hil.estimation.motion import motion_step
from hil.estimation.prefilter import signal_step
from hil.estimation.slots import (
    ACC_STALE,
    GYR_STALE,
    MAG_DISTURBED,
    MAG_STALE,
    NEWTON_FAILED,
    REST,
    pack,
)
from hil.jit import kernel
from hil.so3.floats import apply_f, apply_transpose_f, exp_f

Array = NDArray[np.float64]

CP_MAG_MODE = 0  # MAG_FULL, MAG_HORIZONTAL or MAG_NONE
CP_GATE = 1  # 1: magnetic disturbances are detected (hil.estimation.magnetic)
CP_OMEGA0 = 2  # ω0 (3) rad/s for the measured restart
CP_SIGNAL = 5  # the pre-filter's parameters (pf.SP_SIZE)
CP_GATE_PARAMS = CP_SIGNAL + pf.SP_SIZE  # the magnetic handling's parameters (mg.GP_SIZE)
CP_MOTION_ON = CP_GATE_PARAMS + mg.GP_SIZE  # 1: rest detection and accelerometer trust
CP_MOTION = CP_MOTION_ON + 1  # their parameters (mo.MP_SIZE)
CP_SETTLE = CP_MOTION + mo.MP_SIZE  # s: after the measured restart, restart again at every measurement
CP_SIZE = CP_SETTLE + 1

MAG_FULL = 0  # the field direction as measured
MAG_HORIZONTAL = 1  # its part perpendicular to the measured gravity (heading only)
MAG_NONE = 2  # not used (6-axis)

CS_BIAS = 0  # the initial gyro bias estimate (3) rad/s, b̂ at the start and at a measured restart
CS_AWAITING = 3  # AWAIT_* : where the measured initial attitude stands
CS_T = 4  # the last step's time (s)
CS_IO = 5  # this step's gyr, acc, mag (9)
CS_SIGNAL = CS_IO + 9  # the pre-filter's state (pf.SS_SIZE)
CS_GATE = CS_SIGNAL + pf.SS_SIZE  # the magnetic handling's state (mg.GS_SIZE)
CS_MOTION = CS_GATE + mg.GS_SIZE  # rest detection's and accelerometer trust's state (mo.MS_SIZE)
CS_SETTLE_END = CS_MOTION + mo.MS_SIZE  # s: the time the settling after a measured restart ends
CS_SETTLE_ACC = CS_SETTLE_END + 1  # Σ R_g a over the settling so far (3), the pre-filter's strapdown frame
CS_SETTLE_MAG = CS_SETTLE_ACC + 3  # Σ R_g m (3): the field as the magnetic handling passed it
CS_SIZE = CS_SETTLE_MAG + 3

AWAIT_NONE = 0.0  # the initial attitude is given, or measured already
AWAIT_BOTH = 1.0  # restart from Wahba's solution at the first step with both directions usable
AWAIT_FIELD = 0.5  # restarted from gravity alone (no field yet): restart from Wahba's once there is one

BAD_STEP = v.BAD_STEP


def pack_params(
    signal: Array,
    gate: Array | None,
    mag_mode: int,
    omega_err0: tuple[float, float, float],
    motion: Array | None = None,
    settle_s: float = 0.0,
) -> Array:
    """The chain parameters ``cp``: pre-filter parameters ``signal`` (``pf.pack_signal_params``), magnetic
    handling's (``mg.pack_mag_params``; None: every field sample used), the magnetometer's use
    (``MAG_*``), ω0 (rad/s), rest detection's and accelerometer trust's (``mo.pack_motion_params``; None:
    neither), the settling after a measured restart (s; 0: none)."""
    slots: dict[int, float | ArrayLike] = {
        CP_MAG_MODE: mag_mode,
        CP_OMEGA0: omega_err0,
        CP_SIGNAL: signal,
        CP_SETTLE: settle_s,
    }
    if gate is not None:
        slots[CP_GATE] = 1.0
        slots[CP_GATE_PARAMS] = gate
    if motion is not None:
        slots[CP_MOTION_ON] = 1.0
        slots[CP_MOTION] = motion
    return pack(CP_SIZE, slots)


def new_state(bias: ArrayLike, awaiting: bool) -> Array:
    """A chain state ``cs`` before the first step: the initial bias estimate ``bias`` (3,) rad/s, waiting
    for a measured attitude or not."""
    cs = np.zeros(CS_SIZE)
    cs[CS_BIAS : CS_BIAS + 3] = np.asarray(bias, dtype=float).reshape(3)
    cs[CS_AWAITING] = AWAIT_BOTH if awaiting else AWAIT_NONE
    cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE] = pf.new_signal_state()
    cs[CS_MOTION : CS_MOTION + mo.MS_SIZE] = mo.new_motion_state()
    cs[CS_SETTLE_END] = -math.inf  # no measured restart yet: not settling
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
def tilt(ep, ax, ay, az):  # type: ignore[no-untyped-def]
    """The attitude from gravity alone (no field: 6-axis, or before the first field sample): the shortest
    rotation taking the measured direction ``a`` to E's e1 (up), so the heading is wherever it lands. A
    row-major 9-tuple, body → inertial. ``a``'s squared norm must be positive and finite (the caller's
    check): a compiled kernel's division by zero raises."""
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ux, uy, uz = ax / n, ay / n, az / n
    ex, ey, ez = ep[v.P_E], ep[v.P_E + 3], ep[v.P_E + 6]
    kx, ky, kz = uy * ez - uz * ey, uz * ex - ux * ez, ux * ey - uy * ex  # sin θ · axis
    s = math.sqrt(kx * kx + ky * ky + kz * kz)
    c = ux * ex + uy * ey + uz * ez
    if s < 1e-12:  # parallel (identity) or opposite (half a turn about any perpendicular axis)
        if c > 0.0:
            return (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        px, py, pz = (0.0, -uz, uy) if abs(ux) < 0.9 else (-uz, 0.0, ux)
        p = math.sqrt(px * px + py * py + pz * pz)
        return exp_f(math.pi * px / p, math.pi * py / p, math.pi * pz / p)
    theta = math.atan2(s, c)
    return exp_f(theta * kx / s, theta * ky / s, theta * kz / s)


@kernel
def restart(cp, cs, es, r):  # type: ignore[no-untyped-def]
    """The estimator started over from the attitude ``r`` (row-major 9-tuple) and ω0, counters from zero;
    the gyro bias estimate is kept (what it has learnt so far is still true)."""
    b0, b1, b2 = es[v.S_BIAS], es[v.S_BIAS + 1], es[v.S_BIAS + 2]
    es[:] = 0.0
    for i in range(9):
        es[v.S_R + i] = r[i]
    for i in range(3):
        es[v.S_OMEGA + i] = cp[CP_OMEGA0 + i]
    es[v.S_BIAS], es[v.S_BIAS + 1], es[v.S_BIAS + 2] = b0, b1, b2
    es[v.S_BIAS_TRUST] = es[v.S_MAG_WEIGHT] = 1.0


@kernel
def settle_sum(cs, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """Add the accelerometer ``a`` and the field ``m`` (each left out unless finite), in the pre-filter's
    strapdown frame R_g, to the settling's sums."""
    ss = cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE]
    rg = (ss[0], ss[1], ss[2], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8])
    if math.isfinite(ax + ay + az):
        sx, sy, sz = apply_f(rg, (ax, ay, az))
        cs[CS_SETTLE_ACC] += sx
        cs[CS_SETTLE_ACC + 1] += sy
        cs[CS_SETTLE_ACC + 2] += sz
    if math.isfinite(mx + my + mz):
        sx, sy, sz = apply_f(rg, (mx, my, mz))
        cs[CS_SETTLE_MAG] += sx
        cs[CS_SETTLE_MAG + 1] += sy
        cs[CS_SETTLE_MAG + 2] += sz


@kernel
def settle(cp, cs, ep, es, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """One step of the settling after the measured restart: the step's accelerometer ``a`` (as read) and
    field ``m`` (as the magnetic handling passed it) added to the sums (:func:`settle_sum`), and the
    estimator restarted from Wahba's solution for their means, rotated back to the body.

    Why: the measured restart takes one step's readings, and a recording that starts mid-motion can
    have its accelerometer tens of degrees off gravity there (and the field's horizontal part, taken
    against that wrong vertical, half a turn off): the estimator, a smoothing filter, then climbs out of
    the far start in tens of seconds. Averaged in the strapdown frame, the phone's turning is taken out
    and what is left of the motion is the velocity change over the settling divided by its length; every
    reading counts alike, so a magnetic disturbance at one moment weighs by how long it lasts."""
    settle_sum(cs, ax, ay, az, mx, my, mz)
    ss = cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE]
    rg = (ss[0], ss[1], ss[2], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8])
    sa = (cs[CS_SETTLE_ACC], cs[CS_SETTLE_ACC + 1], cs[CS_SETTLE_ACC + 2])
    sm = (cs[CS_SETTLE_MAG], cs[CS_SETTLE_MAG + 1], cs[CS_SETTLE_MAG + 2])
    bax, bay, baz = apply_transpose_f(rg, sa)
    bmx, bmy, bmz = apply_transpose_f(rg, sm)
    if cp[CP_MAG_MODE] == MAG_HORIZONTAL:  # the field's part perpendicular to the averaged vertical
        na2 = bax * bax + bay * bay + baz * baz
        if 0.0 < na2 < math.inf:
            k = (bmx * bax + bmy * bay + bmz * baz) / na2
            bmx, bmy, bmz = bmx - k * bax, bmy - k * bay, bmz - k * baz
    if both_usable(ep, bax, bay, baz, bmx, bmy, bmz):
        restart(cp, cs, es, wahba(ep, bax, bay, baz, bmx, bmy, bmz))


@kernel
def step(cp, cs, ep, es, t, h, gx, gy, gz, ax, ay, az, mx, my, mz):  # type: ignore[no-untyped-def]
    """One merged step at time ``t`` (s), ``h`` s after the previous one (ignored on the first): raw
    gyr (rad/s), acc (m/s²), mag (NaN: not usable). Returns the estimator step's flags, with
    :attr:`StepFlag.MAG_DISTURBED` when the magnetometer was left out as disturbed and
    :attr:`StepFlag.REST` at rest, ``| newton_updates << ITER_SHIFT``; or :data:`BAD_STEP` (nothing
    changed) for a step after the first whose ``h`` is not a positive number or is too long
    (:func:`~hil.estimation.variational.step_in_range`). A rate reading the estimator cannot use
    (:func:`~hil.estimation.variational.usable_rate`) is NaN to every stage, the pre-filter and the rest
    detector included."""
    ss = cs[CS_SIGNAL : CS_SIGNAL + pf.SS_SIZE]
    started = ss[pf.SS_N] > 0.0
    if started and not v.step_in_range(ep, h):
        return BAD_STEP
    if not v.usable_rate(gx, gy, gz):
        gx = gy = gz = math.nan
    if not started:
        for i in range(3):
            es[v.S_BIAS + i] = cs[CS_BIAS + i]
    bx, by, bz = es[v.S_BIAS], es[v.S_BIAS + 1], es[v.S_BIAS + 2]
    mode = cp[CP_MAG_MODE]
    io = cs[CS_IO : CS_IO + 9]
    io[0], io[1], io[2] = gx - bx, gy - by, gz - bz  # the pre-filter's strapdown frame: gyro less b̂
    io[3], io[4], io[5] = ax, ay, az
    io[6], io[7], io[8] = (math.nan, math.nan, math.nan) if mode == MAG_NONE else (mx, my, mz)
    motion = cp[CP_MOTION_ON] != 0.0
    ms = cs[CS_MOTION : CS_MOTION + mo.MS_SIZE]
    signal_step(cp[CP_SIGNAL : CP_SIGNAL + pf.SP_SIZE], ss, h, io, ms[mo.MS_ACC_CUT] if motion else 1.0)
    flags = 0
    if motion:  # rest and the accelerometer's trust, from the raw acc in the strapdown frame
        sx, sy, sz = apply_f((ss[0], ss[1], ss[2], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8]), (ax, ay, az))
        mp = cp[CP_MOTION : CP_MOTION + mo.MP_SIZE]
        rest = motion_step(mp, ms, h, gx, gy, gz, bx, by, bz, sx, sy, sz)
        es[v.S_BIAS_TRUST] = ms[mo.MS_CALM]  # the bias law trusts the torque as much as gravity's reading
        if rest:
            flags |= REST
            k = min(1.0, h * mp[mo.MP_REST_GAIN])  # at rest the gyro reads its bias: b̂ follows lp(Ω^m)
            lim = ep[v.P_BIAS_MAX]
            for i in range(3):
                b = es[v.S_BIAS + i] + k * (ms[mo.MS_GYR_LP + i] - es[v.S_BIAS + i])
                es[v.S_BIAS + i] = min(lim, max(-lim, b))
    rax, ray, raz = ax, ay, az  # the accelerometer as read (the settling averages it itself)
    ax, ay, az, mx, my, mz = io[3], io[4], io[5], io[6], io[7], io[8]
    # the vertical in the body frame: the estimate's (R̂ᵀ e1) once it runs from a measured or given
    # attitude, else the (pre-filtered) accelerometer's
    if cs[CS_AWAITING] == AWAIT_NONE:
        e0, e1, e2 = ep[v.P_E], ep[v.P_E + 3], ep[v.P_E + 6]
        ux = es[v.S_R] * e0 + es[v.S_R + 3] * e1 + es[v.S_R + 6] * e2
        uy = es[v.S_R + 1] * e0 + es[v.S_R + 4] * e1 + es[v.S_R + 7] * e2
        uz = es[v.S_R + 2] * e0 + es[v.S_R + 5] * e1 + es[v.S_R + 8] * e2
    else:
        na = math.sqrt(ax * ax + ay * ay + az * az)
        ux = uy = uz = math.nan
        if na > 0.0 and math.isfinite(na):
            ux, uy, uz = ax / na, ay / na, az / na
    weight = 1.0
    if cp[CP_GATE] != 0.0 and math.isfinite(mx + my + mz):
        gp = cp[CP_GATE_PARAMS : CP_GATE_PARAMS + mg.GP_SIZE]
        rate = math.sqrt(io[0] * io[0] + io[1] * io[1] + io[2] * io[2])
        weight = mag_step(gp, cs[CS_GATE : CS_GATE + mg.GS_SIZE], h, rate, ux, uy, uz, mx, my, mz)
        if weight < 1.0:  # left out, or at the late weight: disturbed
            flags |= MAG_DISTURBED
        if weight == 0.0:
            mx = my = mz = math.nan
    es[v.S_MAG_WEIGHT] = weight
    gmx, gmy, gmz = mx, my, mz  # the field as the magnetic handling passed it (NaN: left out)
    if mode == MAG_HORIZONTAL:  # the field's part perpendicular to the vertical: heading only
        k = mx * ux + my * uy + mz * uz
        mx, my, mz = mx - k * ux, my - k * uy, mz - k * uz
    awaiting = cs[CS_AWAITING]
    if awaiting == AWAIT_NONE and t < cs[CS_SETTLE_END]:
        settle(cp, cs, ep, es, rax, ray, raz, gmx, gmy, gmz)
    elif awaiting != AWAIT_NONE:
        if both_usable(ep, ax, ay, az, mx, my, mz):
            cs[CS_AWAITING] = AWAIT_NONE  # restart the estimator from the measured attitude
            restart(cp, cs, es, wahba(ep, ax, ay, az, mx, my, mz))
            cs[CS_SETTLE_END] = t + cp[CP_SETTLE]
            for i in range(6):
                cs[CS_SETTLE_ACC + i] = 0.0
            if cp[CP_SETTLE] > 0.0:
                settle_sum(cs, rax, ray, raz, gmx, gmy, gmz)
        elif awaiting == AWAIT_BOTH and 0.0 < ax * ax + ay * ay + az * az < math.inf:
            # a reading whose norm overflows (finite parts, ~1e155 m/s² and up) is no direction here, as
            # everywhere in the chain: tilt would divide by zero
            cs[CS_AWAITING] = AWAIT_NONE if mode == MAG_NONE else AWAIT_FIELD
            restart(cp, cs, es, tilt(ep, ax, ay, az))
    # the estimator takes Ω^m (it removes its own b̂): the pre-filtered gyro with the bias put back
    code = v.step(ep, es, h, io[0] + bx, io[1] + by, io[2] + bz, ax, ay, az, mx, my, mz)
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
        gx, gy, gz = (nan, nan, nan) if fi & GYR_STALE else (gyr[i, 0], gyr[i, 1], gyr[i, 2])
        ax, ay, az = (nan, nan, nan) if fi & ACC_STALE else (acc[i, 0], acc[i, 1], acc[i, 2])
        mx, my, mz = (nan, nan, nan) if fi & MAG_STALE else (mag[i, 0], mag[i, 1], mag[i, 2])
        h = t[i] - cs[CS_T] if cs[CS_SIGNAL + pf.SS_N] > 0.0 else 0.0
        code = step(cp, cs, ep, es, t[i], h, gx, gy, gz, ax, ay, az, mx, my, mz)
        if code < 0:
            return i
        v.write_row(es, i, out_r, out_omega, out_w)
        out_flags[i] = fi | (code & v.FLAG_BITS)
        out_iters[i] = code >> v.ITER_SHIFT
        if stop and code & NEWTON_FAILED:
            return i + 1
    return n

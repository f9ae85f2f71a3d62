"""Numpy references for the estimator's compiled kernels: straightforward transcriptions, one step at a
time, with numpy 3×3 algebra (:mod:`hil.so3.arrays`), written from the equations rather than from the
kernels' scalar code. The tests compare every kernel with them to rounding; nothing runs them at run time.

- :func:`measurement`, :func:`potential`, :func:`torque`, :func:`newton`, :func:`advance`, :func:`run` —
  :mod:`hil.estimation.variational` (U⁰ from its definition ``½⟨E_S − R̂U_S, (E_S − R̂U_S) W_SS⟩``);
- :func:`strapdown_frames`, :func:`signal_run` (the closed-form :func:`~hil.estimation.prefilter.
  filter_batch` in either frame), :func:`gate_run` — :mod:`hil.estimation.prefilter`;
- :func:`filter_run` — the whole chain of :mod:`hil.estimation.chain` (Wahba's attitude by
  :func:`hil.estimation.params.wahba`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.filter import FilterConfig
from hil.estimation.params import EstimatorParams, wahba
from hil.estimation.prefilter import GateSettings, filter_batch
from hil.estimation.sensors import KINDS, MergedSteps, SensorKind, StepFlag

Array = NDArray[np.float64]

_DEGENERATE = int(StepFlag.DEGENERATE)
_NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)
_SUBSTEPPED = int(StepFlag.SUBSTEPPED)
_GYR_STALE = int(StepFlag.GYR_STALE)
_MAG_DISTURBED = int(StepFlag.MAG_DISTURBED)


# --------------------------------------------------------------------------- the variational step
@dataclass(frozen=True)
class Measurement:
    """One step's directions: ``U`` (3, 3) with the unusable columns zero, ``used`` (3,) bool (acc, mag,
    acc×mag), ``L = E W_SS Uᵀ`` (3, 3), ``flags``."""

    U: Array
    used: NDArray[np.bool_]
    L: Array
    flags: int

    @property
    def mask(self) -> int:
        return int(self.used[0]) | 2 * int(self.used[1]) | 4 * int(self.used[2])


def _unit(v: ArrayLike | None) -> Array | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(a))
    return a / n if math.isfinite(n) and n > 0.0 else None


def measurement(p: EstimatorParams, acc: ArrayLike | None, mag: ArrayLike | None) -> Measurement:
    """The usable directions of one step and ``L`` (see :mod:`hil.estimation.variational`)."""
    u1, u2, u3 = _unit(acc), _unit(mag), None
    flags = 0
    if u1 is not None and u2 is not None:
        c = np.cross(u1, u2)
        if np.linalg.norm(c) >= math.sin(math.radians(p.min_direction_angle_deg)):
            u3 = c / np.linalg.norm(c)
        else:
            flags |= _DEGENERATE
            u2 = None
    used = np.array([u is not None for u in (u1, u2, u3)])
    u = np.column_stack([np.zeros(3) if x is None else x for x in (u1, u2, u3)])
    s = np.diag(used.astype(float))
    return Measurement(u, used, p.E @ (s @ p.W @ s) @ u.T, flags)


def potential(p: EstimatorParams, r: Array, meas: Measurement) -> float:
    """``U⁰ = ½ ⟨E_S − R̂ U_S, (E_S − R̂ U_S) W_SS⟩`` over the usable directions."""
    s = np.diag(meas.used.astype(float))
    diff = p.E @ s - r @ meas.U
    return 0.5 * float(np.trace(diff.T @ diff @ (s @ p.W @ s)))


def torque(p: EstimatorParams, r: Array, meas: Measurement) -> Array:
    """``Φ'(U⁰) S_L(R̂)``, ``S_L = vex(Lᵀ R̂ − R̂ᵀ L)``; zero without a usable direction."""
    if not meas.used.any():
        return np.zeros(3)
    return p.phi.derivative(potential(p, r, meas)) * so3.vee(meas.L.T @ r - r.T @ meas.L)


def left_jacobian(phi: Array) -> Array:
    """``J_l(φ) = I + (1 − cos θ)/θ² φ^× + (θ − sin θ)/θ³ (φ^×)²`` (series where the closed forms cancel)."""
    t2 = float(phi @ phi)
    t = math.sqrt(t2)
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0 if t < 1e-4 else 2.0 * math.sin(0.5 * t) ** 2 / t2
    c = (
        sum((-t2) ** k / math.factorial(2 * k + 3) for k in range(10))
        if t < 1.0
        else (t - math.sin(t)) / t**3
    )
    k = so3.hat(phi)
    return np.eye(3) + b * k + c * k @ k


def newton(p: EstimatorParams, hh: float, g1: Array, c: Array) -> tuple[Array, int, bool]:
    """Solve ``m ω = exp(hh (ω − g1)^×) c`` for ω: a fixed-point start, then Newton with
    ``J = m I + hh y^× J_l(φ)``, stopping at ``‖f‖/m ≤ tol √(1 + ‖ω‖²)``. Returns (ω, updates, converged)."""
    m = p.m
    w = so3.exp(hh * (c / m - g1)) @ c / m
    for it in range(p.newton_max_iter + 1):
        phi = hh * (w - g1)
        y = so3.exp(phi) @ c
        f = m * w - y
        if np.linalg.norm(f) / m <= p.newton_tol * math.sqrt(1.0 + float(w @ w)):
            return w, it, True
        if it == p.newton_max_iter or not np.all(np.isfinite(f)):
            break
        w = w - np.linalg.solve(m * np.eye(3) + hh * so3.hat(y) @ left_jacobian(phi), f)
    return w, p.newton_max_iter, False


def advance(
    p: EstimatorParams, r: Array, w: Array, g0: Array, tau0: Array, h: float, g1: Array, meas: Measurement
) -> tuple[Array, Array, Array, int, bool]:
    """Proposition 1 from (R̂[i], ω[i]) to i+1 (see :func:`hil.estimation.variational.advance`)."""
    m, hh, eye = p.m, 0.5 * h, np.eye(3)
    w_half = np.linalg.solve(m * eye + hh * p.D, so3.exp(-hh * (g0 - w)) @ (m * w) + hh * tau0)
    r1 = r @ so3.exp(h * (0.5 * (g0 + g1) - w_half))
    r1 = r1 @ (1.5 * eye - 0.5 * r1.T @ r1)  # one Newton–Schulz polar step, as the kernel
    tau1 = torque(p, r1, meas)
    w1, iters, ok = newton(p, hh, g1, (m * eye - hh * p.D) @ w_half + hh * tau1)
    return r1, w1, tau1, iters, ok


@dataclass
class RunResult:
    """:func:`run`'s outputs (N steps) and counters."""

    R: Array
    omega: Array
    omega_err: Array
    flags: NDArray[np.int64]
    iterations: NDArray[np.int64]
    counters: dict[str, int] = field(default_factory=dict)


def run(
    p: EstimatorParams, r0: ArrayLike, w0: ArrayLike, t: Array, gyr: Array, acc: Array, mag: Array
) -> RunResult:
    """The estimator over N steps at times ``t`` from ``(R̂0, ω0)``: rows with a NaN are not usable; the
    first step only initialises; long steps are sub-stepped (gyro interpolated, measurement held)."""
    n = len(t)
    out = RunResult(np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.zeros(n, np.int64),
                    np.zeros(n, np.int64))  # fmt: skip
    cnt = dict.fromkeys(("substeps", "newton_updates", "max_newton_updates", "no_direction"), 0)
    r, w = np.array(r0, dtype=float), np.array(w0, dtype=float)
    g0 = tau = np.zeros(3)
    for i in range(n):
        g1 = gyr[i] if np.all(np.isfinite(gyr[i])) else np.zeros(3)
        flags = 0 if np.all(np.isfinite(gyr[i])) else _GYR_STALE
        meas = measurement(p, acc[i], mag[i])
        flags |= meas.flags
        total = 0
        if i == 0:
            tau = torque(p, r, meas)
        else:
            h = t[i] - t[i - 1]
            n_sub = 1 if h <= p.max_step_s else math.ceil(h / p.max_step_s)
            if n_sub > 1:
                flags |= _SUBSTEPPED
            start = g0
            for j in range(1, n_sub + 1):
                ga = start + j / n_sub * (g1 - start) if j < n_sub else g1
                r, w, tau, iters, ok = advance(p, r, w, g0, tau, h / n_sub, ga, meas)
                g0 = ga
                total += iters
                flags |= 0 if ok else _NEWTON_FAILED
            cnt["substeps"] += n_sub - 1
        g0 = g1
        out.R[i], out.omega[i], out.omega_err[i] = r, g1 - w, w
        out.flags[i], out.iterations[i] = flags, total
        cnt["newton_updates"] += total
        cnt["max_newton_updates"] = max(cnt["max_newton_updates"], total)
        cnt["no_direction"] += int(not meas.used.any())
    out.counters = cnt
    return out


# --------------------------------------------------------------------------- pre-filter and gate
def strapdown_frames(h: Array, gyr: Array) -> Array:
    """``R_g`` (N, 3, 3) at each step: the gyro (non-finite rows read as 0) integrated by the midpoint
    rule from the identity, one Newton–Schulz polar step after each product."""
    g = np.where(np.all(np.isfinite(gyr), axis=1)[:, None], gyr, 0.0)
    frames = np.empty((len(h), 3, 3))
    r = np.eye(3)
    for k in range(len(h)):
        if k:
            r = r @ so3.exp(0.5 * h[k] * (g[k - 1] + g[k]))
            r = r @ (1.5 * np.eye(3) - 0.5 * r.T @ r)
        frames[k] = r
    return frames


def signal_run(
    cutoffs: dict[SensorKind, float | None], frame: str, h: Array, gyr: Array, acc: Array, mag: Array
) -> tuple[Array, Array, Array]:
    """The three signals through the closed-form pre-filter (NaN rows: not usable), acc and mag in the
    strapdown frame if ``frame == "strapdown"``."""
    frames = strapdown_frames(h, gyr) if frame == "strapdown" else None
    out = []
    for kind, v in zip(KINDS, (gyr, acc, mag), strict=True):
        cut = cutoffs.get(kind)
        if cut is None:
            out.append(v)
        elif frames is None or kind is SensorKind.GYR:
            out.append(filter_batch(h, v, cut))
        else:
            y = filter_batch(h, np.einsum("nij,nj->ni", frames, v), cut)
            out.append(np.einsum("nji,nj->ni", frames, y))
    return out[0], out[1], out[2]


def gate_run(settings: GateSettings, h: Array, up: Array, mag: Array) -> NDArray[np.bool_]:
    """Which magnetometer rows pass the gate (see :class:`hil.estimation.prefilter.MagneticGate`)."""
    sin_tol = math.sin(math.radians(settings.dip_tol_deg))
    norm: float | None = None
    dip_ref: float | None = None
    rejected_for = 0.0
    passed = np.zeros(len(h), dtype=bool)
    for i in range(len(h)):
        n = float(np.linalg.norm(mag[i]))
        if not (math.isfinite(n) and n > 0.0):
            continue
        nu = float(np.linalg.norm(up[i]))
        dip = -float(up[i] @ mag[i]) / (nu * n) if math.isfinite(nu) and nu > 0.0 else None
        if norm is None:
            norm, dip_ref, passed[i] = n, dip, True
            continue
        ok = abs(n / norm - 1.0) <= settings.norm_tol
        if dip is not None and dip_ref is not None:
            ok = ok and abs(dip - dip_ref) <= sin_tol
        if not ok:
            rejected_for += h[i]
            if rejected_for < settings.timeout_s:
                continue
            norm, dip_ref = n, dip
        rejected_for = 0.0
        k = min(1.0, h[i] / settings.tau_s)
        norm += k * (n - norm)
        if dip is not None:
            dip_ref = dip if dip_ref is None else dip_ref + k * (dip - dip_ref)
        passed[i] = True
    return passed


# --------------------------------------------------------------------------- the chain
def filter_run(config: FilterConfig, steps: MergedSteps) -> RunResult:
    """The attitude filter (``config``: a :class:`hil.estimation.filter.FilterConfig`) over ``steps``
    from a fresh start: bias, pre-filter, gate, horizontal magnetometer, measured initial attitude, then
    :func:`run`. Flags include the merger's and MAG_DISTURBED."""
    h = steps.h
    gyr, acc, mag = (np.where(steps.valid(k)[:, None], steps.value(k), np.nan) for k in KINDS)
    gyr = gyr - np.asarray(config.gyro_bias)
    gyr, acc, mag = signal_run(config.prefilter_rad_s, config.prefilter_frame, h, gyr, acc, mag)
    flags = steps.flags.copy()
    if config.mag_gate is not None:
        finite = np.all(np.isfinite(mag), axis=1)
        passed = gate_run(config.mag_gate, h, acc, mag)
        flags |= np.where(finite & ~passed, _MAG_DISTURBED, 0)
        mag = np.where(passed[:, None], mag, np.nan)
    if config.magnetometer == "horizontal":
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.sum(mag * acc, axis=1) / np.sum(acc * acc, axis=1)
        mag = mag - k[:, None] * acc
    p = config.params
    measured = isinstance(config.init, str) and config.init == "measured"
    r0 = np.eye(3) if isinstance(config.init, str) else np.asarray(config.init, dtype=float)
    start = 0
    if measured:
        usable = [bool(measurement(p, a, m).used.all()) for a, m in zip(acc, mag, strict=True)]
        start = usable.index(True) if any(usable) else len(steps)
    parts = []
    if start:
        parts.append(run(p, r0, config.omega_err0, steps.t[:start], gyr[:start], acc[:start], mag[:start]))
    if start < len(steps):
        if measured:
            r0 = wahba(p, acc[start], mag[start])
        s = slice(start, None)
        parts.append(run(p, r0, config.omega_err0, steps.t[s], gyr[s], acc[s], mag[s]))
    fields = ("R", "omega", "omega_err", "flags", "iterations")
    out = RunResult(*(np.concatenate([getattr(x, f) for x in parts]) for f in fields))  # type: ignore[arg-type]
    out.flags |= flags
    out.counters = parts[-1].counters
    return out

"""Numpy references for the estimator's compiled kernels: straightforward transcriptions, one step at a
time, with numpy 3×3 algebra (:mod:`hil.so3.arrays`), written from the equations rather than from the
kernels' scalar code. The tests compare every kernel with them to rounding; nothing runs them at run time.

- :func:`measurement`, :func:`potential`, :func:`torque`, :func:`newton`, :func:`advance`,
  :class:`Estimator`, :func:`run` — :mod:`hil.estimation.variational` (U⁰ from its definition
  ``½⟨E_S − R̂U_S, (E_S − R̂U_S) W_SS⟩``, the gyro bias law);
- :func:`strapdown_frames`, :func:`signal_run` (the closed-form :func:`~hil.estimation.prefilter.
  filter_batch` in either frame) — :mod:`hil.estimation.prefilter`;
- the motion and magnetic stages and the whole chain: :mod:`hil.estimation.reference_chain`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.params import EstimatorParams
from hil.estimation.prefilter import filter_batch
from hil.estimation.sensors import KINDS, SensorKind
from hil.estimation.slots import DEGENERATE, GYR_STALE, GYRO_LIMIT, NEWTON_FAILED, SUBSTEPPED

Array = NDArray[np.float64]

_NAN3 = np.full(3, np.nan)


# --------------------------------------------------------------------------- the variational step
@dataclass(frozen=True)
class Measurement:
    """One step's directions: ``U`` (3, 3) with the unusable columns zero (the field's scaled by its
    weight), ``used`` (3,) bool (acc, mag, acc×mag), ``L = E W_SS Uᵀ`` (3, 3), ``flags``."""

    U: Array
    used: NDArray[np.bool_]
    L: Array
    flags: int

    @property
    def mask(self) -> int:
        return int(self.used[0]) | 2 * int(self.used[1]) | 4 * int(self.used[2])


def unit(v: ArrayLike | None) -> Array | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(a))
    return a / n if math.isfinite(n) and n > 0.0 else None


def measurement(
    p: EstimatorParams, acc: ArrayLike | None, mag: ArrayLike | None, mag_weight: float = 1.0
) -> Measurement:
    """The usable directions of one step and ``L`` (see :mod:`hil.estimation.variational`); the field's
    column of U is scaled by ``mag_weight``."""
    u1, u2, u3 = unit(acc), unit(mag), None
    flags = 0
    if u1 is not None and u2 is not None:
        c = np.cross(u1, u2)
        if np.linalg.norm(c) >= math.sin(math.radians(p.min_direction_angle_deg)):
            u3 = c / np.linalg.norm(c)
        else:
            flags |= DEGENERATE
            u2 = None
    used = np.array([u is not None for u in (u1, u2, u3)])
    if u2 is not None:
        u2 = mag_weight * u2
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


def bias_rate(p: EstimatorParams, tau: Array, trust: float, up: Array) -> Array:
    """``P⁻¹ τ'`` with ``τ' = γ τ + (ν − γ)(τ·u) u`` (γ the trust, ν ``bias_vertical``, u the vertical)."""
    t = trust * tau + (p.bias_vertical - trust) * float(tau @ up) * up
    return np.asarray(p.bias_gain) * t


def advance(
    p: EstimatorParams,
    r: Array,
    w: Array,
    b: Array,
    g0: Array,
    tau0: Array,
    h: float,
    g1: Array,
    meas: Measurement,
    trust: float = 1.0,
    up: Array | None = None,
) -> tuple[Array, Array, Array, Array, int, bool]:
    """Proposition 1 with the gyro bias estimate from (R̂[i], ω[i], b̂[i]) to i+1 (see
    :func:`hil.estimation.variational.advance`)."""
    m, hh, eye = p.m, 0.5 * h, np.eye(3)
    u = np.zeros(3) if up is None else up
    clip = lambda x: np.clip(x, -p.bias_max, p.bias_max)  # noqa: E731
    b_half = clip(b + hh * bias_rate(p, tau0, trust, u))
    w_half = np.linalg.solve(m * eye + hh * p.D, so3.exp(-hh * (g0 - b - w)) @ (m * w) + hh * tau0)
    rate = g0 + (0.5 + p.gyro_delay_s / h) * (g1 - g0)  # the readings at the step's middle, delayed
    r1 = r @ so3.exp(h * (rate - b_half - w_half))
    r1 = r1 @ (1.5 * eye - 0.5 * r1.T @ r1)  # one Newton–Schulz polar step, as the kernel
    tau1 = torque(p, r1, meas)
    b1 = clip(b_half + hh * bias_rate(p, tau1, trust, u))
    w1, iters, ok = newton(p, hh, g1 - b1, (m * eye - hh * p.D) @ w_half + hh * tau1)
    return r1, w1, b1, tau1, iters, ok


@dataclass
class Estimator:
    """The estimator's state, stepped one merged step at a time (:meth:`step`): R̂, ω, b̂, the last
    rate measurement and the cached torque; counters."""

    p: EstimatorParams
    r: Array
    w: Array
    b: Array = field(default_factory=lambda: np.zeros(3))
    g0: Array = field(default_factory=lambda: np.zeros(3))
    tau: Array = field(default_factory=lambda: np.zeros(3))
    started: bool = False
    counters: dict[str, int] = field(
        default_factory=lambda: dict.fromkeys(
            ("substeps", "newton_updates", "max_newton_updates", "no_direction"), 0
        )
    )

    def step(
        self, h: float, gyr: Array, acc: Array, mag: Array, mag_weight: float = 1.0, trust: float = 1.0
    ) -> tuple[int, int]:
        """One step: the first only initialises; a long one is sub-stepped (gyro interpolated, measurement
        held). Returns (flags, Newton updates)."""
        p = self.p
        ok_g = bool(np.all(np.abs(gyr) <= GYRO_LIMIT))  # NaN fails too
        g1 = np.asarray(gyr, dtype=float) if ok_g else np.zeros(3)
        flags = 0 if ok_g else GYR_STALE
        meas = measurement(p, acc, mag, mag_weight)
        flags |= meas.flags
        up = unit(acc)
        up = np.zeros(3) if up is None else up
        total = 0
        if not self.started:
            self.started = True
            self.tau = torque(p, self.r, meas)
        else:
            n_sub = 1 if h <= p.max_step_s else math.ceil(h / p.max_step_s)
            if n_sub > 1:
                flags |= SUBSTEPPED
            start = self.g0
            for j in range(1, n_sub + 1):
                ga = start + j / n_sub * (g1 - start) if j < n_sub else g1
                self.r, self.w, self.b, self.tau, iters, ok = advance(
                    p, self.r, self.w, self.b, self.g0, self.tau, h / n_sub, ga, meas, trust, up
                )
                self.g0 = ga
                total += iters
                flags |= 0 if ok else NEWTON_FAILED
            self.counters["substeps"] += n_sub - 1
        self.g0 = g1
        self.counters["newton_updates"] += total
        self.counters["max_newton_updates"] = max(self.counters["max_newton_updates"], total)
        self.counters["no_direction"] += int(not meas.used.any())
        return flags, total

    @property
    def rate(self) -> Array:
        """Ω̂ = Ω^m − b̂ − ω."""
        return self.g0 - self.b - self.w


@dataclass
class RunResult:
    """:func:`run`'s outputs (N steps) and counters."""

    R: Array
    omega: Array
    omega_err: Array
    flags: NDArray[np.int64]
    iterations: NDArray[np.int64]
    bias: Array
    counters: dict[str, int] = field(default_factory=dict)

    @classmethod
    def empty(cls, n: int) -> RunResult:
        return cls(
            np.empty((n, 3, 3)),
            np.empty((n, 3)),
            np.empty((n, 3)),
            np.zeros(n, np.int64),
            np.zeros(n, np.int64),
            np.empty((n, 3)),
        )

    def record(self, i: int, est: Estimator, flags: int, iters: int) -> None:
        self.R[i], self.omega[i], self.omega_err[i], self.bias[i] = est.r, est.rate, est.w, est.b
        self.flags[i], self.iterations[i] = flags, iters


def run(
    p: EstimatorParams,
    r0: ArrayLike,
    w0: ArrayLike,
    t: Array,
    gyr: Array,
    acc: Array,
    mag: Array,
    b0: ArrayLike = (0.0, 0.0, 0.0),
) -> RunResult:
    """The estimator over N steps at times ``t`` from ``(R̂0, ω0, b̂0)``: rows with a NaN are not usable;
    the first step only initialises; long steps are sub-stepped (gyro interpolated, measurement held)."""
    n = len(t)
    out = RunResult.empty(n)
    est = Estimator(p, np.array(r0, dtype=float), np.array(w0, dtype=float), np.array(b0, dtype=float))
    for i in range(n):
        flags, iters = est.step(t[i] - t[i - 1] if i else 0.0, gyr[i], acc[i], mag[i])
        out.record(i, est, flags, iters)
    out.counters = est.counters
    return out


# --------------------------------------------------------------------------- pre-filter
def strapdown_frames(h: Array, gyr: Array, delay_s: float = 0.0) -> Array:
    """``R_g`` (N, 3, 3) at each step: the gyro (non-finite rows read as 0) integrated from the identity
    at the step's middle moved forward by ``delay_s``, one Newton–Schulz polar step after each product."""
    g = np.where(np.all(np.isfinite(gyr), axis=1)[:, None], gyr, 0.0)
    frames = np.empty((len(h), 3, 3))
    r = np.eye(3)
    for k in range(len(h)):
        if k:
            r = r @ strapdown_step(h[k], g[k - 1], g[k], delay_s)
            r = r @ (1.5 * np.eye(3) - 0.5 * r.T @ r)
        frames[k] = r
    return frames


def strapdown_step(h: float, g0: Array, g1: Array, delay_s: float) -> Array:
    """The gyro-only frame's rotation over one step."""
    return so3.exp(h * (g0 + (0.5 + delay_s / h) * (g1 - g0)))


def signal_run(
    cutoffs: dict[SensorKind, float | None], frame: str, h: Array, gyr: Array, acc: Array, mag: Array
) -> tuple[Array, Array, Array]:
    """The three signals through the closed-form pre-filter (NaN rows: not usable), acc and mag in the
    strapdown frame if ``frame == "strapdown"``. There a row not usable while the gyro is usable is left
    out of the filter (it comes out NaN; the filter goes on from the row before it, the gap's time not
    counted); one where the gyro is not usable either resets it."""
    frames = strapdown_frames(h, gyr) if frame == "strapdown" else None
    gyro_ok = np.all(np.isfinite(gyr), axis=1)
    out = []
    for kind, v in zip(KINDS, (gyr, acc, mag), strict=True):
        cut = cutoffs.get(kind)
        if cut is None:
            out.append(v)
        elif frames is None or kind is SensorKind.GYR:
            out.append(filter_batch(h, v, cut))
        else:
            rows = np.all(np.isfinite(v), axis=1) | ~gyro_ok
            y = np.full_like(v, np.nan)
            y[rows] = filter_batch(h[rows], np.einsum("nij,nj->ni", frames[rows], v[rows]), cut)
            out.append(np.einsum("nji,nj->ni", frames, y))
    return out[0], out[1], out[2]


class Lowpass:
    """The first-order Tustin low-pass of a 3-vector, one step at a time, with a per-step cut-off; a
    non-finite input gives NaN and resets it (:meth:`hold` gives NaN and keeps it)."""

    def __init__(self) -> None:
        self.x: Array | None = None
        self.y: Array | None = None

    def __call__(self, h: float, x: Array, cutoff: float) -> Array:
        if not np.all(np.isfinite(x)):
            self.x = self.y = None
            return _NAN3.copy()
        if self.x is None or self.y is None:
            self.x, self.y = x.copy(), x.copy()
            return x.copy()
        a, b = (2.0 - cutoff * h) / (2.0 + cutoff * h), cutoff * h / (2.0 + cutoff * h)
        self.y = a * self.y + b * (self.x + x)
        self.x = x.copy()
        return self.y.copy()

    def hold(self) -> Array:
        """A step without a usable input that keeps the state (the strapdown frame with a usable gyro)."""
        return _NAN3.copy()

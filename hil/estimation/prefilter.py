"""The paper's first-order Butterworth low-pass pre-filter, discretised by the bilinear (Tustin) transform.

Continuous filter with cut-off ``ω_c`` (rad/s): ``H(s) = ω_c / (s + ω_c)``, i.e. ``dx̄/dt = ω_c (x − x̄)``.
Substituting ``s = (2/h)(z − 1)/(z + 1)`` over a step of ``h`` seconds and multiplying by ``h (z + 1)``:

    (2 + ω_c h) x̄[k+1] = (2 − ω_c h) x̄[k] + ω_c h (x[k] + x[k+1])

which with the paper's ``ω_c = 1 rad/s`` is its ``(2 + h) x̄[k+1] = (2 − h) x̄[k] + h (x[k] + x[k+1])``.
The step ``h`` may change from sample to sample (jittered phone timestamps): each step uses its own.
The DC gain is exactly 1 for every ``h``; for ``ω_c h < 2`` the pole ``(2 − ω_c h)/(2 + ω_c h)`` is in
(0, 1) (no ringing), and it stays inside the unit circle for any ``h > 0`` (the Tustin map is A-stable).

Initial condition: the filter starts at its first valid input (``x̄[0] = x[0]``, the steady state for a
constant input), so a 9.81 m/s² gravity reading does not ramp up from zero. An invalid input (``valid``
false, or any non-finite component) yields NaN and resets the filter, which restarts at the next valid
sample: after a sensor drop-out the output follows the fresh data instead of sliding over from the old.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.sensors import KINDS, MergedSteps, SensorKind
from hil.so3 import Mat9, Vec3, apply_f, apply_transpose_f, exp_f, matmul_f, reorthonormalize_f
from protocol.errors import ConfigError

Array = NDArray[np.float64]

PAPER_CUTOFF_RAD_S = 1.0
"""The paper's cut-off frequency (rad/s)."""


def _check_cutoff(cutoff_rad_s: float) -> float:
    if not (math.isfinite(cutoff_rad_s) and cutoff_rad_s > 0.0):
        raise ConfigError(f"pre-filter cut-off must be a positive number of rad/s, got {cutoff_rad_s!r}")
    return float(cutoff_rad_s)


def coefficients(cutoff_rad_s: float, h: Any) -> tuple[Any, Any]:
    """``(α, β)`` with ``x̄[k+1] = α x̄[k] + β (x[k] + x[k+1])`` for a step of ``h`` seconds (a float, or
    an array of steps giving arrays)."""
    wh = cutoff_rad_s * h
    return (2.0 - wh) / (2.0 + wh), wh / (2.0 + wh)


class Prefilter:
    """Per-sample first-order Butterworth low-pass of a ``dim``-vector (e.g. an accelerometer triad).

    ``update(h, x)`` takes the step ``h`` (s, > 0) since the previous sample and the new input ``x``
    (shape (dim,)); it returns the filtered value as a tuple of floats. The first call (or the first after
    a reset) ignores ``h`` and returns ``x`` itself.
    """

    __slots__ = ("cutoff_rad_s", "dim", "_x", "_y")

    def __init__(self, cutoff_rad_s: float = PAPER_CUTOFF_RAD_S, dim: int = 3) -> None:
        self.cutoff_rad_s = _check_cutoff(cutoff_rad_s)
        self.dim = dim
        self._x: tuple[float, ...] | None = None  # previous input
        self._y: tuple[float, ...] | None = None  # previous output

    def reset(self) -> None:
        """Forget the past; the next valid sample restarts the filter."""
        self._x = self._y = None

    @property
    def output(self) -> tuple[float, ...] | None:
        """The latest filtered value, or None before the first valid sample (or after a reset)."""
        return self._y

    def update(self, h: float, x: Sequence[float] | ArrayLike, valid: bool = True) -> tuple[float, ...]:
        """Filter one sample; an invalid or non-finite one returns NaNs and resets the filter."""
        xs = x if type(x) is tuple else tuple(float(v) for v in np.asarray(x, dtype=float).reshape(-1))
        if len(xs) != self.dim:
            raise ValueError(f"pre-filter input has {len(xs)} components, expected {self.dim}")
        if not valid or not all(math.isfinite(v) for v in xs):
            self.reset()
            return (math.nan,) * self.dim
        if self._y is None or self._x is None:
            self._x = self._y = xs
            return xs
        if not h > 0.0:
            raise ValueError(f"pre-filter step must be positive, got h = {h!r} s")
        a, b = coefficients(self.cutoff_rad_s, h)
        y = tuple(a * yp + b * (xp + xn) for yp, xp, xn in zip(self._y, self._x, xs, strict=True))
        self._x, self._y = xs, y
        return y


def filter_batch(h: ArrayLike, x: ArrayLike, cutoff_rad_s: float = PAPER_CUTOFF_RAD_S) -> Array:
    """Filter a whole signal: ``x`` (N, dim) sampled with steps ``h`` (N,) — ``h[k]`` is the step that
    ends at sample ``k`` (``h[0]`` is ignored). Rows with a non-finite value are invalid: they come out
    NaN and reset the filter (see the module docstring). Returns (N, dim); the same numbers (to rounding)
    as :class:`Prefilter` fed sample by sample, at numpy speed for any steps.

    The recursion ``y[k] = α_k y[k−1] + u_k`` (``u_k = β_k (x[k−1] + x[k])``) is solved in closed form,
    ``y[k] = Q_k (y[s] + Σ_{j≤k} u_j / Q_j)`` with ``Q_k = Π α`` since the block start ``s``; blocks are cut
    so that ``Q`` stays above 1e-260 (no underflow; the sum's rounding stays at the scale of ``y``).
    """
    cutoff = _check_cutoff(cutoff_rad_s)
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        return filter_batch(h, x[:, None], cutoff)[:, 0]
    h = np.asarray(h, dtype=float).reshape(-1)
    if h.shape[0] != x.shape[0]:
        raise ValueError(f"step array has {h.shape[0]} entries for {x.shape[0]} samples")
    out = np.full_like(x, np.nan)
    valid = np.all(np.isfinite(x), axis=1)
    if valid.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], valid.astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            out[start:stop] = _filter_run(h[start + 1 : stop], x[start:stop], cutoff)
    return out


_BLOCK_LOG = 600.0  # a block ends before Π α falls below e^-600 ≈ 1e-261


def _filter_run(h: Array, x: Array, cutoff: float) -> Array:
    """Filter a run of valid samples, starting at ``x[0]``; ``h`` (len(x) − 1,) are the steps between."""
    if np.any(~(h > 0.0)):
        k = int(np.flatnonzero(~(h > 0.0))[0])
        raise ValueError(f"pre-filter steps must be positive: step {k + 1} is {h[k]!r} s")
    y = np.empty_like(x)
    y[0] = x[0]
    if len(x) < 2:
        return y
    alpha, beta = coefficients(cutoff, h)
    u = beta[:, None] * (x[:-1] + x[1:])
    if np.any(alpha <= 1e-40):  # ω_c h ≥ 2: steps far too long for the cut-off; plain recursion
        for k in range(1, len(x)):
            y[k] = alpha[k - 1] * y[k - 1] + u[k - 1]
        return y
    log_q = np.cumsum(np.log(alpha))
    block = np.floor(-log_q / _BLOCK_LOG).astype(np.int64)
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(block)) + 1, [len(u)]])
    carry = x[0]
    for i, j in zip(cuts[:-1], cuts[1:], strict=True):
        q = np.exp(log_q[i:j] - (log_q[i - 1] if i > 0 else 0.0))[:, None]
        y[i + 1 : j + 1] = q * (carry + np.cumsum(u[i:j] / q, axis=0))
        carry = y[j]
    return y


# --------------------------------------------------------------------------- a phone's three signals
class SignalPrefilter:
    """The pre-filter for a phone's three measured quantities, stepped together over merged steps.

    ``cutoffs`` (rad/s) per :class:`SensorKind`; None leaves that signal unfiltered. ``frame``:

    - ``"body"`` — the paper: each signal filtered as measured, in the body frame. A direction measured in
      a turning body then lags the body by ~1/ω_c s (a 1 rad/s filter on a phone turning at 0.3 rad/s
      is ~17° late).
    - ``"strapdown"`` — the accelerometer and magnetometer vectors are filtered in a frame that follows the
      gyroscope alone (``R_g``, the gyro integrated by the midpoint rule from the first step, never
      corrected) and rotated back to the body: the same low-pass on what the sensors see of gravity and
      the field, without the rotation lag (``R_g`` drifts only with the gyro bias, far slower than the
      filter). The gyroscope itself, if given a cut-off, is filtered in the body frame.

    A signal that is None (not usable) comes out None and its filter restarts at its next usable sample.
    """

    def __init__(self, cutoffs: dict[SensorKind, float | None], frame: str = "body") -> None:
        if frame not in ("body", "strapdown"):
            raise ConfigError(
                f"pre-filter frame must be 'body' or 'strapdown', got {frame!r}", "prefilter frame"
            )
        self.frame = frame
        self._cut = {k: cutoffs.get(k) for k in KINDS}
        self._filters = {k: Prefilter(float(c)) for k, c in self._cut.items() if c is not None}
        self._r: Mat9 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self._g: Vec3 = (0.0, 0.0, 0.0)
        self._n = 0

    def step(
        self, h: float, gyr: Vec3 | None, acc: Vec3 | None, mag: Vec3 | None
    ) -> tuple[Vec3 | None, Vec3 | None, Vec3 | None]:
        """One merged step of ``h`` s (ignored on the first); returns the filtered (gyr, acc, mag)."""
        g = gyr if gyr is not None else (0.0, 0.0, 0.0)
        strap = self.frame == "strapdown"
        if strap and self._n:
            a = self._g
            r = matmul_f(
                self._r, exp_f(0.5 * h * (a[0] + g[0]), 0.5 * h * (a[1] + g[1]), 0.5 * h * (a[2] + g[2]))
            )
            self._r = reorthonormalize_f(r)
        self._g = g
        self._n += 1
        out_g = self._filter(SensorKind.GYR, h, gyr, None)
        frame = self._r if strap else None
        return out_g, self._filter(SensorKind.ACC, h, acc, frame), self._filter(SensorKind.MAG, h, mag, frame)

    def _filter(self, kind: SensorKind, h: float, v: Vec3 | None, r: Mat9 | None) -> Vec3 | None:
        f = self._filters.get(kind)
        if f is None:
            return v
        if v is None:
            f.reset()
            return None
        y = f.update(h, v if r is None else apply_f(r, v))  # in the strapdown frame: R_g v
        return y if r is None else apply_transpose_f(r, y)  # type: ignore[return-value,arg-type]

    def run(self, steps: MergedSteps) -> MergedSteps:
        """Filter every step at once (same numbers, to rounding, as :meth:`step` one by one); the filter
        state is not carried into or out of a batch. Stale sensors stay NaN."""
        h = steps.h
        values = {k: np.where(steps.valid(k)[:, None], steps.value(k), np.nan) for k in KINDS}
        frames = self._strapdown_frames(h, values[SensorKind.GYR]) if self.frame == "strapdown" else None
        out = {}
        for kind in KINDS:
            cut, v = self._cut[kind], values[kind]
            if cut is None:
                out[kind] = v
            elif frames is None or kind is SensorKind.GYR:
                out[kind] = filter_batch(h, v, cut)
            else:
                y = filter_batch(h, np.einsum("nij,nj->ni", frames, v), cut)
                out[kind] = np.einsum("nji,nj->ni", frames, y)
        return replace(steps, gyr=out[SensorKind.GYR], acc=out[SensorKind.ACC], mag=out[SensorKind.MAG])

    @staticmethod
    def _strapdown_frames(h: Array, gyr: Array) -> Array:
        """``R_g`` (N, 3, 3) at each step: the gyro (NaN read as 0) integrated by the midpoint rule."""
        g = np.where(np.isfinite(gyr), gyr, 0.0)
        mid = 0.5 * h[1:, None] * (g[:-1] + g[1:])
        steps = so3.exp(mid).reshape(-1, 9).tolist()
        r: Mat9 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        frames = [r]
        for step in steps:
            r = reorthonormalize_f(matmul_f(r, step))  # type: ignore[arg-type]
            frames.append(r)
        return np.asarray(frames, dtype=float).reshape(len(h), 3, 3)


# --------------------------------------------------------------------------- magnetic disturbances
@dataclass(frozen=True)
class GateSettings:
    """:class:`MagneticGate` settings: norm tolerance (fraction), dip tolerance (deg), reference time
    constant (s), rejection timeout (s)."""

    norm_tol: float = 0.1
    dip_tol_deg: float = 8.0
    tau_s: float = 20.0
    timeout_s: float = 10.0


class MagneticGate:
    """Rejects magnetometer samples that a local disturbance (steel, magnets, electronics) has bent.

    The geomagnetic field has a fixed strength and a fixed angle to gravity (the dip); a disturbance
    changes one or both. A sample is rejected when its norm is more than ``norm_tol`` (fraction) from the
    reference norm, or its dip — the angle to the gravity direction given (e.g. the pre-filtered
    accelerometer) — more than ``dip_tol_deg`` from the reference dip. References start at the first
    sample and follow accepted samples with time constant ``tau_s``; after ``timeout_s`` of continuous
    rejection the gate accepts again and re-learns (a changed environment, not a passing disturbance).
    Rejected samples come out None (flagged :attr:`StepFlag.MAG_DISTURBED` by the caller).
    """

    def __init__(
        self, norm_tol: float = 0.1, dip_tol_deg: float = 8.0, tau_s: float = 20.0, timeout_s: float = 10.0
    ):
        for name, v in (
            ("norm_tol", norm_tol),
            ("dip_tol_deg", dip_tol_deg),
            ("tau_s", tau_s),
            ("timeout_s", timeout_s),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"must be a positive number, got {v!r}", f"MagneticGate.{name}")
        self.norm_tol, self.sin_tol, self.tau_s, self.timeout_s = (
            norm_tol,
            math.sin(math.radians(dip_tol_deg)),
            tau_s,
            timeout_s,
        )
        self._norm: float | None = None
        self._dip: float | None = None  # sin of the dip: −(ĝ·m̂), ĝ = gravity reading direction (up)
        self._rejected_for = 0.0

    def step(self, h: float, up: Vec3 | None, mag: Vec3 | None) -> Vec3 | None:
        if mag is None:
            return None
        n = math.sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        if not n > 0.0:
            return None
        dip = None
        if up is not None:
            nu = math.sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2])
            if nu > 0.0:
                dip = -(up[0] * mag[0] + up[1] * mag[1] + up[2] * mag[2]) / (nu * n)
        if self._norm is None:
            self._norm, self._dip = n, dip
            return mag
        ok = abs(n / self._norm - 1.0) <= self.norm_tol
        if dip is not None and self._dip is not None:
            ok = ok and abs(dip - self._dip) <= self.sin_tol
        if not ok:
            self._rejected_for += h
            if self._rejected_for < self.timeout_s:
                return None
            self._norm, self._dip = n, dip  # the environment changed: start over from here
        self._rejected_for = 0.0
        k = min(1.0, h / self.tau_s)
        self._norm += k * (n - self._norm)
        if dip is not None:
            self._dip = dip if self._dip is None else self._dip + k * (dip - self._dip)
        return mag

    def run(self, h: Array, up: Array, mag: Array) -> Array:
        """Gate every step (the same numbers as :meth:`step` one by one); rejected rows come out NaN."""
        out = mag.copy()
        for i, (hi, u, m) in enumerate(zip(h.tolist(), up.tolist(), mag.tolist(), strict=True)):
            kept = self.step(hi, _finite3(u), _finite3(m))
            if kept is None:
                out[i] = np.nan
        return out


def _finite3(v: list[float]) -> Vec3 | None:
    x, y, z = v
    return (x, y, z) if math.isfinite(x + y + z) else None

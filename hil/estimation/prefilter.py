"""The paper's first-order Butterworth low-pass pre-filter, discretised by the bilinear (Tustin) transform
— compiled kernels and the objects around them.

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
The strapdown frame (:class:`SignalPrefilter`) is the exception: there the gyro keeps the old state true
(gravity and the field do not move in ``R_g``'s frame), so acc and mag keep their filter's state through
a drop-out while the gyro is usable, and restart only if it is not either — a restart from the first
sample after a drop-out would take a hand-held phone's jolt for steady state.

Compiled (:func:`hil.jit.kernel`): :func:`lowpass` (one sample of a filter of any dimension),
:func:`signal_step` (a phone's three signals, body or strapdown frame); the attitude filter's chain
(:mod:`hil.estimation.chain`) runs them inside its own kernel. Their arrays (float64; slots are the
constants below):

- a low-pass state (``1 + 2 d`` for dimension d): running flag, previous input (d), previous output (d);
- signal parameters ``sp`` (:data:`SP_SIZE`): the cut-offs of gyr, acc, mag (rad/s; 0 = not filtered),
  strapdown flag; signal state ``ss`` (:data:`SS_SIZE`): the strapdown frame ``R_g`` (9), the last gyro
  (3), steps taken, then the three low-pass states (gyr, acc, mag).

:func:`filter_batch` is the filter in closed form on numpy arrays (the numpy reference the tests compare
:func:`lowpass` with); :mod:`hil.estimation.reference` has the others.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.sensors import KINDS, MergedSteps, SensorKind
from hil.estimation.slots import pack
from hil.jit import kernel
from hil.so3.floats import apply_f, apply_transpose_f, exp_f, matmul_f, reorthonormalize_f
from protocol.errors import ConfigError

Array = NDArray[np.float64]

PAPER_CUTOFF_RAD_S = 1.0
"""The paper's cut-off frequency (rad/s)."""

BAD_STEP = -1
"""What :func:`lowpass` and :func:`signal_step` return for a step ``h`` that is not a positive number."""

SP_CUTOFF = 0  # cut-offs (3) rad/s in KINDS order, 0 = not filtered
SP_STRAPDOWN = 3  # 1: acc and mag filtered in the gyro-only frame
SP_GYRO_DELAY = 4  # s the gyro's readings lag the motion (R_g's midpoint rule moved forward by it)
SP_SIZE = 5

SS_RG = 0  # R_g (9), the gyro integrated alone
SS_GYR = 9  # the last gyro (3), non-finite read as 0
SS_N = 12  # steps taken
SS_LP = 13  # three low-pass states of LP_SIZE (gyr, acc, mag)
LP_SIZE = 7  # a 3-vector's low-pass state: running, previous input (3), previous output (3)
SS_SIZE = SS_LP + 3 * LP_SIZE

_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _check_cutoff(cutoff_rad_s: float) -> float:
    if not (math.isfinite(cutoff_rad_s) and cutoff_rad_s > 0.0):
        raise ConfigError(f"pre-filter cut-off must be a positive number of rad/s, got {cutoff_rad_s!r}")
    return float(cutoff_rad_s)


def coefficients(cutoff_rad_s: float, h: Any) -> tuple[Any, Any]:
    """``(α, β)`` with ``x̄[k+1] = α x̄[k] + β (x[k] + x[k+1])`` for a step of ``h`` seconds (a float, or
    an array of steps giving arrays)."""
    wh = cutoff_rad_s * h
    return (2.0 - wh) / (2.0 + wh), wh / (2.0 + wh)


# --------------------------------------------------------------------------- kernels
@kernel
def lowpass(st, cutoff, h, x, y):  # type: ignore[no-untyped-def]
    """One sample ``x`` (d,) through the low-pass whose state is ``st`` (1 + 2d), output into ``y`` (d,)
    (``y`` may be ``x`` itself). Returns 1 for a filtered value, 0 for an invalid input (``y`` NaN, the
    filter reset), :data:`BAD_STEP` (nothing changed) for a running filter and an ``h`` that is not a
    positive number. The first valid sample (or the first after a reset) ignores ``h``."""
    d = x.shape[0]
    for i in range(d):
        if not math.isfinite(x[i]):
            st[0] = 0.0
            y[:] = math.nan
            return 0
    if st[0] == 0.0:
        st[0] = 1.0
        for i in range(d):
            st[1 + i] = x[i]
            st[1 + d + i] = x[i]
            y[i] = x[i]
        return 1
    if not (h > 0.0 and math.isfinite(h)):
        return BAD_STEP
    wh = cutoff * h
    a, b = (2.0 - wh) / (2.0 + wh), wh / (2.0 + wh)
    for i in range(d):
        xi = x[i]
        yi = a * st[1 + d + i] + b * (st[1 + i] + xi)
        st[1 + i] = xi
        st[1 + d + i] = yi
        y[i] = yi
    return 1


@kernel
def signal_step(sp, ss, h, io, acc_scale):  # type: ignore[no-untyped-def]
    """One merged step of ``h`` s (ignored on the first) through a phone's three signals: ``io`` (9,)
    holds gyr, acc, mag (NaN: not usable) and receives them filtered (NaN where not usable; a signal that
    is not filtered passes through). In the strapdown frame, acc and mag are filtered as ``R_g v`` and
    rotated back (see :class:`SignalPrefilter`); there a step where acc (or mag) is not usable but the gyro
    is keeps that filter's state (``R_g`` still follows the body), one where the gyro is not either
    resets it. The accelerometer's cut-off is multiplied by
    ``acc_scale`` for this step (its trust: :mod:`hil.estimation.motion`; 1 for the configured cut-off).
    Returns 0, or :data:`BAD_STEP` (nothing changed) for a step after the first whose ``h`` is not a
    positive number."""
    if ss[SS_N] > 0.0 and not (h > 0.0 and math.isfinite(h)):
        return BAD_STEP
    gx, gy, gz = io[0], io[1], io[2]
    gyro_ok = math.isfinite(gx + gy + gz)
    if not gyro_ok:
        gx = gy = gz = 0.0
    strap = sp[SP_STRAPDOWN] != 0.0
    r = (ss[0], ss[1], ss[2], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8])
    if strap and ss[SS_N] > 0.0:
        ax, ay, az = ss[SS_GYR], ss[SS_GYR + 1], ss[SS_GYR + 2]
        f = 0.5 + sp[SP_GYRO_DELAY] / h  # the rate at the step's middle, as the estimator takes it
        r = reorthonormalize_f(
            matmul_f(r, exp_f(h * (ax + f * (gx - ax)), h * (ay + f * (gy - ay)), h * (az + f * (gz - az))))
        )
        for i in range(9):
            ss[SS_RG + i] = r[i]
    ss[SS_GYR], ss[SS_GYR + 1], ss[SS_GYR + 2] = gx, gy, gz
    ss[SS_N] += 1.0
    for s in range(3):
        cut = sp[SP_CUTOFF + s]
        if cut == 0.0:
            continue
        if s == 1:
            cut *= acc_scale
        v = io[3 * s : 3 * s + 3]
        st = ss[SS_LP + LP_SIZE * s : SS_LP + LP_SIZE * (s + 1)]
        if strap and s > 0 and math.isfinite(v[0] + v[1] + v[2]):  # filter R_g v, rotate back
            v[0], v[1], v[2] = apply_f(r, (v[0], v[1], v[2]))
            lowpass(st, cut, h, v, v)
            v[0], v[1], v[2] = apply_transpose_f(r, (v[0], v[1], v[2]))
        elif strap and s > 0 and gyro_ok:  # not usable: R_g carries the filter's state through the gap
            v[:] = math.nan
        else:
            lowpass(st, cut, h, v, v)
    return 0


@kernel
def _signal_run(sp, ss, h, io):  # type: ignore[no-untyped-def]
    """:func:`signal_step` over N steps: ``h`` (N,), ``io`` (N, 9) in place. Returns the index of a bad
    step, or N."""
    for i in range(h.shape[0]):
        if signal_step(sp, ss, h[i], io[i], 1.0) < 0:
            return i
    return h.shape[0]


# --------------------------------------------------------------------------- one signal
class Prefilter:
    """Per-sample first-order Butterworth low-pass of a ``dim``-vector (e.g. an accelerometer triad).

    ``update(h, x)`` takes the step ``h`` (s, > 0) since the previous sample and the new input ``x``
    (shape (dim,)); it returns the filtered value as a tuple of floats. The first call (or the first after
    a reset) ignores ``h`` and returns ``x`` itself.
    """

    __slots__ = ("cutoff_rad_s", "dim", "_st", "_y")

    def __init__(self, cutoff_rad_s: float = PAPER_CUTOFF_RAD_S, dim: int = 3) -> None:
        self.cutoff_rad_s = _check_cutoff(cutoff_rad_s)
        self.dim = dim
        self._st = np.zeros(1 + 2 * dim)
        self._y = np.empty(dim)

    def reset(self) -> None:
        """Forget the past; the next valid sample restarts the filter."""
        self._st[0] = 0.0

    @property
    def output(self) -> tuple[float, ...] | None:
        """The latest filtered value, or None before the first valid sample (or after a reset)."""
        return tuple(self._st[1 + self.dim :].tolist()) if self._st[0] else None

    def update(self, h: float, x: ArrayLike, valid: bool = True) -> tuple[float, ...]:
        """Filter one sample; an invalid or non-finite one returns NaNs and resets the filter."""
        xs = np.asarray(x, dtype=float).reshape(-1)
        if xs.shape[0] != self.dim:
            raise ValueError(f"pre-filter input has {xs.shape[0]} components, expected {self.dim}")
        if not valid:
            self.reset()
            return (math.nan,) * self.dim
        if lowpass(self._st, self.cutoff_rad_s, float(h), xs, self._y) < 0:
            raise ValueError(f"pre-filter step must be positive, got h = {h!r} s")
        return tuple(self._y.tolist())


def filter_batch(h: ArrayLike, x: ArrayLike, cutoff_rad_s: float = PAPER_CUTOFF_RAD_S) -> Array:
    """Filter a whole signal in closed form (the numpy reference for :func:`lowpass`): ``x`` (N, dim)
    sampled with steps ``h`` (N,) — ``h[k]`` is the step that ends at sample ``k`` (``h[0]`` is ignored).
    Rows with a non-finite value are invalid: they come out NaN and reset the filter (see the module
    docstring). Returns (N, dim); the same numbers (to rounding) as :class:`Prefilter` fed sample by
    sample.

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
def pack_signal_params(
    cutoffs: dict[SensorKind, float | None], frame: str, gyro_delay_s: float = 0.0
) -> Array:
    """The signal parameters ``sp`` (:data:`SP_SIZE`) for per-sensor ``cutoffs`` (None: not filtered) and
    the gyroscope's delay (s, see :class:`hil.estimation.params.EstimatorParams`)."""
    if frame not in ("body", "strapdown"):
        raise ConfigError(f"pre-filter frame must be 'body' or 'strapdown', got {frame!r}", "prefilter frame")
    cut = [cutoffs.get(kind) for kind in KINDS]
    return pack(
        SP_SIZE,
        {
            SP_CUTOFF: [0.0 if c is None else _check_cutoff(float(c)) for c in cut],
            SP_STRAPDOWN: 1.0 if frame == "strapdown" else 0.0,
            SP_GYRO_DELAY: gyro_delay_s,
        },
    )


def new_signal_state() -> Array:
    """A signal state ``ss`` (:data:`SS_SIZE`) before the first step: ``R_g`` = I, filters not running."""
    ss = np.zeros(SS_SIZE)
    ss[SS_RG : SS_RG + 9] = _IDENTITY
    return ss


Vec = tuple[float, float, float]


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

    A signal that is None (not usable) comes out None. In the body frame, and in the strapdown frame when
    the gyro is not usable either, its filter restarts at its next usable sample; in the strapdown frame
    with a usable gyro, acc's and mag's filters keep their state through the gap (``R_g`` keeps it true)
    and go on from it, the gap's time not counted.
    :meth:`step` and :meth:`run` run the same kernel and continue from the same state.
    """

    def __init__(self, cutoffs: dict[SensorKind, float | None], frame: str = "body") -> None:
        self.frame = frame
        self._sp = pack_signal_params(cutoffs, frame)
        self._ss = new_signal_state()
        self._io = np.empty(9)

    def step(
        self, h: float, gyr: Vec | None, acc: Vec | None, mag: Vec | None
    ) -> tuple[Vec | None, Vec | None, Vec | None]:
        """One merged step of ``h`` s (ignored on the first); returns the filtered (gyr, acc, mag)."""
        io = self._io
        for s, v in enumerate((gyr, acc, mag)):
            io[3 * s : 3 * s + 3] = math.nan if v is None else v
        if signal_step(self._sp, self._ss, float(h), io, 1.0) < 0:
            raise ValueError(f"pre-filter step must be positive, got h = {h!r} s")
        out = io.tolist()
        g, a, m = (_vec(out[3 * s : 3 * s + 3]) for s in range(3))
        return g, a, m

    def run(self, steps: MergedSteps) -> MergedSteps:
        """Filter every step in one compiled call (the same numbers as :meth:`step` one by one). Stale
        sensors come out NaN."""
        values = [np.where(steps.valid(k)[:, None], steps.value(k), np.nan) for k in KINDS]
        io = np.ascontiguousarray(np.concatenate(values, axis=1))
        h = np.ascontiguousarray(steps.h, dtype=float)
        done = _signal_run(self._sp, self._ss, h, io)
        if done < len(h):
            raise ValueError(f"pre-filter steps must be positive: step {done} is {h[done]!r} s")
        return replace(steps, gyr=io[:, 0:3], acc=io[:, 3:6], mag=io[:, 6:9])


def _vec(v: list[float]) -> Vec | None:
    x, y, z = v
    return (x, y, z) if math.isfinite(x + y + z) else None

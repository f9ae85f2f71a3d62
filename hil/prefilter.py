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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.errors import ConfigError

Array = NDArray[np.float64]

PAPER_CUTOFF_RAD_S = 1.0
"""The paper's cut-off frequency (rad/s)."""


def _check_cutoff(cutoff_rad_s: float) -> float:
    if not (math.isfinite(cutoff_rad_s) and cutoff_rad_s > 0.0):
        raise ConfigError(f"pre-filter cut-off must be a positive number of rad/s, got {cutoff_rad_s!r}")
    return float(cutoff_rad_s)


def coefficients(cutoff_rad_s: float, h: float) -> tuple[float, float]:
    """``(α, β)`` with ``x̄[k+1] = α x̄[k] + β (x[k] + x[k+1])`` for a step of ``h`` seconds."""
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
        xs = tuple(float(v) for v in np.asarray(x, dtype=float).reshape(-1))
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
    NaN and reset the filter (see the module docstring). Returns (N, dim); same numbers as
    :class:`Prefilter` fed sample by sample.

    Each run of valid rows is filtered at once: with a constant step by ``scipy.signal.lfilter`` (the
    common case of a resampled or merged stream), otherwise by the explicit recursion.
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


def _filter_run(h: Array, x: Array, cutoff: float) -> Array:
    """Filter a run of valid samples, starting at ``x[0]``; ``h`` (len(x) − 1,) are the steps between."""
    if np.any(~(h > 0.0)):
        k = int(np.flatnonzero(~(h > 0.0))[0])
        raise ValueError(f"pre-filter steps must be positive: step {k + 1} is {h[k]!r} s")
    if len(x) < 2:
        return x.copy()
    if np.ptp(h) <= 1e-12 * h[0]:
        from scipy.signal import lfilter

        a, b = coefficients(cutoff, float(h[0]))
        # lfilter's direct-form-II-transposed state z = b·x[k] + a·y[k], started from y[0] = x[0]
        zi = ((a + b) * x[0])[None, :]
        y = np.empty_like(x)
        y[0] = x[0]
        y[1:] = lfilter([b, b], [1.0, -a], x[1:], axis=0, zi=zi)[0]
        return y
    alpha, beta = coefficients(cutoff, h)
    y = np.empty_like(x)
    rows = x.tolist()
    prev_y = rows[0]
    prev_x = rows[0]
    y[0] = prev_y
    for k in range(1, len(rows)):
        a = float(alpha[k - 1])
        b = float(beta[k - 1])
        xn = rows[k]
        prev_y = [a * yp + b * (xp + xv) for yp, xp, xv in zip(prev_y, prev_x, xn, strict=True)]
        prev_x = xn
        y[k] = prev_y
    return y

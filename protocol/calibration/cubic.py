"""Monotone piecewise-cubic Hermite tables: the one curve primitive every calibration map is built from.

A table is ``n`` knots (2 ≤ n ≤ 16) ``x[k]`` strictly increasing, values ``y[k]`` and slopes ``m[k]``
(dy/dx at the knots). Between knots it is the cubic Hermite interpolant, so evaluating it needs only the
stored numbers: no fitting code on the board. Slopes are chosen at fit time by PCHIP (Fritsch–Carlson with
Brodlie's weighted harmonic mean, the same as ``scipy.interpolate.PchipInterpolator``), which keeps the
curve monotone between monotone data. Tables are strictly monotone (no two equal values) and the stored
slopes have the sign of the table and satisfy ``|m[k]| ≤ 3·|δ|`` for both intervals they touch (``δ`` the
interval's secant): that box inside the Fritsch–Carlson region guarantees a monotone cubic on every
interval, which makes the inverse well posed.

The algorithms here are the reference for ``docs/calibration.md`` §2: written in Horner form, with a
fixed iteration cap, so a float32 C port follows them line by line.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..compiled import fast_constructor
from ..errors import CalibrationError
from .checks import F32_MAX, f32, finite32
from .conversion import Clamp, Conversion

MAX_KNOTS = 16
SOLVE_MAX_ITER = 20
"""Safeguarded-Newton passes for the inverse (2–3 are typical; the cap bounds a C port's time)."""
SOLVE_TOL_T = 1e-6
"""Stop when a Newton step moves the interval parameter t (0..1) by at most this."""
SLOPE_TOLERANCE = 1e-5
"""Relative slack on the ``|m| ≤ 3|δ|`` check when *validating* stored slopes (float32 rounding)."""

_U32 = struct.Struct("<I")
_SLOPE_SLACK = f32(1.0 + f32(SLOPE_TOLERANCE))  # the firmware's ``1.0f + SLOPE_TOLERANCE``
_BIG_VALUE = 2.0**64
_SMALL_VALUE = 2.0**-64
_conversion = fast_constructor(Conversion)
"""``Conversion(value, clamp)`` by setting its slots, not through the frozen dataclass's ``__init__``
(``object.__setattr__`` per field): one per conversion, ~7 000 gimbal pulses a default run."""
_NONE = Clamp.NONE

_Interval = tuple[float, float, float, float, float, float, float]
"""One interval's constants: (x0, h, y0, y1 - y0, a1, a2, a3), each computed as the reference's
:meth:`MonotoneCubic.evaluate_reference` / :meth:`MonotoneCubic.solve_reference` compute it per call."""


@dataclass(frozen=True, slots=True)
class _Plan:
    """What a table's conversions compute from the table alone, computed once
    (:meth:`MonotoneCubic._plan_of`): a table is immutable, so these are the bits the reference recomputes
    at every call. ``first``, ``last``: x's ends; ``s`` (±1.0: rising or falling), ``lo``/``hi`` (the
    value range); the clamped answers as
    :class:`Conversion` objects (immutable: one each, shared); per interval its constants
    (:data:`_Interval`), and y at the interval's right knot for the inverse's search."""

    first: float
    last: float
    s: float
    lo: float
    hi: float
    below_x: Conversion  # evaluate: x < x[0]
    above_x: Conversion  # evaluate: x > x[-1]
    below_y: Conversion  # solve: y < lo
    above_y: Conversion  # solve: y > hi
    intervals: tuple[_Interval, ...]
    right_x: tuple[float, ...]  # x[k + 1] of interval k
    right_y: tuple[float, ...]  # y[k + 1] of interval k


@dataclass(frozen=True, slots=True)
class MonotoneCubic:
    """A strictly monotone cubic Hermite table. ``x``, ``y``, ``slopes``: tuples of n float32-exact floats.

    Build one with :meth:`pchip` from knots; the constructor validates (raising :class:`CalibrationError`
    whose ``where`` names the knot) and rounds every number to float32 so that the binary format round-trips
    exactly. The table rises (``y[0] < y[1] < …``) or falls (``y[0] > y[1] > …``).
    """

    x: tuple[float, ...]
    y: tuple[float, ...]
    slopes: tuple[float, ...]
    _plan: _Plan | None = field(default=None, init=False, repr=False, compare=False, hash=False)
    """The table's per-interval constants for :meth:`evaluate` and :meth:`solve` (built with the table)."""

    def __post_init__(self) -> None:
        x = tuple(finite32(v, f"x[{k}]") for k, v in enumerate(self.x))
        y = tuple(finite32(v, f"y[{k}]") for k, v in enumerate(self.y))
        m = tuple(finite32(v, f"slope[{k}]") for k, v in enumerate(self.slopes))
        n = len(x)
        if not 2 <= n <= MAX_KNOTS:
            raise CalibrationError(f"{n} knots; a table has 2 to {MAX_KNOTS}", "knots")
        if len(y) != n or len(m) != n:
            raise CalibrationError(f"{n} x, {len(y)} y and {len(m)} slopes; need equal counts", "knots")
        for k in range(n - 1):
            if not x[k] < x[k + 1]:
                raise CalibrationError(
                    f"x must increase strictly ({x[k]!r} then {x[k + 1]!r})", f"x[{k + 1}]"
                )
        rising = y[-1] > y[0]
        if y[-1] == y[0]:
            raise CalibrationError("first and last values are equal: the table is flat", "y")
        for k in range(n - 1):
            _check_interval(k, x, y, m, rising)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "slopes", m)
        object.__setattr__(self, "_plan", self._plan_of())

    def _plan_of(self) -> _Plan:
        """The table's :class:`_Plan`: each number by the very operations the reference performs per call
        (``x[k + 1] - x[k]``, :meth:`_coefficients`), so a conversion through it gives the same bits."""
        xs, ys = self.x, self.y
        intervals = []
        for k in range(len(xs) - 1):
            h = xs[k + 1] - xs[k]
            y0, a1, a2, a3 = self._coefficients(k, h)
            intervals.append((xs[k], h, y0, ys[k + 1] - y0, a1, a2, a3))
        rising = self.rising
        lo, hi = self.y_range
        return _Plan(
            first=xs[0],
            last=xs[-1],
            s=1.0 if rising else -1.0,
            lo=lo,
            hi=hi,
            below_x=Conversion(ys[0], Clamp.LOW),
            above_x=Conversion(ys[-1], Clamp.HIGH),
            below_y=Conversion(xs[0] if rising else xs[-1], Clamp.LOW),
            above_y=Conversion(xs[-1] if rising else xs[0], Clamp.HIGH),
            intervals=tuple(intervals),
            right_x=xs[1:],
            right_y=ys[1:],
        )

    # ------------------------------------------------------------------ construction
    @classmethod
    def pchip(cls, x: Sequence[float], y: Sequence[float]) -> MonotoneCubic:
        """The PCHIP table through knots (``x`` strictly increasing, ``y`` strictly monotone), rounded to
        float32."""
        xs = tuple(finite32(v, f"x[{k}]") for k, v in enumerate(x))
        ys = tuple(finite32(v, f"y[{k}]") for k, v in enumerate(y))
        if len(xs) != len(ys) or len(xs) < 2:
            raise CalibrationError(f"{len(xs)} x and {len(ys)} y; need equal counts of at least 2", "knots")
        if any(not a < b for a, b in zip(xs, xs[1:], strict=False)):
            raise CalibrationError("x must increase strictly", "x")
        slopes = pchip_slopes(xs, ys)
        limited = tuple(_limit_slope(k, xs, ys, s) for k, s in enumerate(slopes))
        return cls(xs, ys, limited)

    # ------------------------------------------------------------------ properties
    @property
    def rising(self) -> bool:
        """True if ``y`` increases with ``x``."""
        return self.y[-1] > self.y[0]

    @property
    def x_range(self) -> tuple[float, float]:
        return self.x[0], self.x[-1]

    @property
    def y_range(self) -> tuple[float, float]:
        """(lowest, highest) value of the table, whichever its direction."""
        return (self.y[0], self.y[-1]) if self.rising else (self.y[-1], self.y[0])

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, x: float) -> Conversion:
        """y(x); ``x`` outside ``[x[0], x[-1]]`` is clamped to the nearest end and flagged.

        :meth:`evaluate_reference`'s operations on the table's precomputed constants (:class:`_Plan`):
        the same bits for every input, NaN included (``tests/test_hunt9_k_calibration_plan.py``)."""
        plan = self._plan
        assert plan is not None  # set by __post_init__
        if x < plan.first:
            return plan.below_x
        if x > plan.last:
            return plan.above_x
        k = 0
        last = len(plan.intervals) - 1
        right = plan.right_x
        while k < last and x >= right[k]:
            k += 1
        x0, h, y0, _, a1, a2, a3 = plan.intervals[k]
        t = (x - x0) / h
        return _conversion(y0 + t * (a1 + t * (a2 + t * a3)), _NONE)

    def solve(self, y: float) -> Conversion:
        """The x with y(x) = ``y`` (the inverse). ``y`` outside the table's value range is clamped to the
        end of ``x`` holding the nearest value and flagged LOW/HIGH by ``y``'s side.

        :meth:`solve_reference`'s operations on the table's precomputed constants (:class:`_Plan`): the
        same bits for every input, NaN included (``tests/test_hunt9_k_calibration_plan.py``)."""
        plan = self._plan
        assert plan is not None  # set by __post_init__
        if y < plan.lo:
            return plan.below_y
        if y > plan.hi:
            return plan.above_y
        s = plan.s
        k = 0
        last = len(plan.intervals) - 1
        right = plan.right_y
        while k < last and s * (y - right[k]) > 0.0:
            k += 1
        x0, h, y0, d, a1, a2, a3 = plan.intervals[k]
        t = _solve_interval(y - y0, s, a1, a2, a3, (y - y0) / d)
        return _conversion(x0 + t * h, _NONE)

    def evaluate_reference(self, x: float) -> Conversion:
        """The reference of :meth:`evaluate` (``docs/calibration.md`` §2, what a C port follows), kept as
        its tests' oracle: y(x); ``x`` outside ``[x[0], x[-1]]`` is clamped to the nearest end and flagged."""
        xs = self.x
        if x < xs[0]:
            return Conversion(self.y[0], Clamp.LOW)
        if x > xs[-1]:
            return Conversion(self.y[-1], Clamp.HIGH)
        k = 0
        last = len(xs) - 2
        while k < last and x >= xs[k + 1]:
            k += 1
        h = xs[k + 1] - xs[k]
        t = (x - xs[k]) / h
        y0, a1, a2, a3 = self._coefficients(k, h)
        return Conversion(y0 + t * (a1 + t * (a2 + t * a3)))

    def solve_reference(self, y: float) -> Conversion:
        """The reference of :meth:`solve` (``docs/calibration.md`` §2, what a C port follows), kept as its
        tests' oracle: the x with y(x) = ``y`` (the inverse). ``y`` outside the table's value range is
        clamped to the end of ``x`` holding the nearest value and flagged LOW/HIGH by ``y``'s side."""
        ys = self.y
        lo, hi = self.y_range
        if y < lo:
            return Conversion(self.x[0] if self.rising else self.x[-1], Clamp.LOW)
        if y > hi:
            return Conversion(self.x[-1] if self.rising else self.x[0], Clamp.HIGH)
        s = 1.0 if self.rising else -1.0
        k = 0
        last = len(ys) - 2
        while k < last and s * (y - ys[k + 1]) > 0.0:
            k += 1
        x0 = self.x[k]
        h = self.x[k + 1] - x0
        y0, a1, a2, a3 = self._coefficients(k, h)
        t = _solve_interval(y - y0, s, a1, a2, a3, (y - y0) / (ys[k + 1] - y0))
        return Conversion(x0 + t * h)

    def _coefficients(self, k: int, h: float) -> tuple[float, float, float, float]:
        """(y0, a1, a2, a3) of y = y0 + t·(a1 + t·(a2 + t·a3)) on interval k, t = (x - x[k]) / h."""
        y0 = self.y[k]
        d = self.y[k + 1] - y0
        hm0 = h * self.slopes[k]
        hm1 = h * self.slopes[k + 1]
        return y0, hm0, 3.0 * d - 2.0 * hm0 - hm1, hm0 + hm1 - 2.0 * d


def _solve_interval(target: float, s: float, a1: float, a2: float, a3: float, t: float) -> float:
    """t in [0, 1] with t·(a1 + t·(a2 + t·a3)) = ``target`` on a monotone cubic of direction ``s``:
    Newton from the secant guess ``t``, kept inside a shrinking bracket (bisection when a step leaves it
    or the derivative is not positive)."""
    lo, hi = 0.0, 1.0
    for _ in range(SOLVE_MAX_ITER):
        e = s * (t * (a1 + t * (a2 + t * a3)) - target)
        if e == 0.0:
            break
        if e > 0.0:
            hi = t
        else:
            lo = t
        g = s * (a1 + t * (2.0 * a2 + 3.0 * t * a3))
        tn = t - e / g if g > 0.0 else 0.5 * (lo + hi)
        if not lo < tn < hi:
            tn = 0.5 * (lo + hi)
        done = abs(tn - t) <= SOLVE_TOL_T
        t = tn
        if done:
            break
    return t


def pchip_slopes(x: Sequence[float], y: Sequence[float]) -> tuple[float, ...]:
    """PCHIP knot slopes, exactly as ``scipy.interpolate.PchipInterpolator`` computes them.

    Interior knots: 0 where the neighbouring secants differ in sign or either is 0, else Brodlie's weighted
    harmonic mean ``(w1 + w2) / (w1/δ[k-1] + w2/δ[k])``, ``w1 = 2h[k] + h[k-1]``, ``w2 = h[k] + 2h[k-1]``.
    End knots: the one-sided three-point formula, set to 0 if its sign differs from the end secant's and
    limited to 3× that secant where the two end secants differ in sign. Two knots: the secant.
    """
    n = len(x)
    h = [x[k + 1] - x[k] for k in range(n - 1)]
    d = [(y[k + 1] - y[k]) / h[k] for k in range(n - 1)]
    if n == 2:
        return (d[0], d[0])
    m = [0.0] * n
    for k in range(1, n - 1):
        if d[k - 1] == 0.0 or d[k] == 0.0 or (d[k - 1] > 0.0) != (d[k] > 0.0):
            continue
        w1 = 2.0 * h[k] + h[k - 1]
        w2 = h[k] + 2.0 * h[k - 1]
        m[k] = (w1 + w2) / (w1 / d[k - 1] + w2 / d[k])
    m[0] = _edge_slope(h[0], h[1], d[0], d[1])
    m[-1] = _edge_slope(h[-1], h[-2], d[-1], d[-2])
    return tuple(m)


def _edge_slope(h0: float, h1: float, d0: float, d1: float) -> float:
    s = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
    if _sign(s) != _sign(d0):
        return 0.0
    if _sign(d0) != _sign(d1) and abs(s) > 3.0 * abs(d0):
        return 3.0 * d0
    return s


def _sign(v: float) -> int:
    return (v > 0.0) - (v < 0.0)


def _check_interval(
    k: int, x: tuple[float, ...], y: tuple[float, ...], m: tuple[float, ...], rising: bool
) -> None:
    """Strictly monotone in the table's direction, and slopes inside the box that keeps the cubic monotone.

    The box is checked in float32, operation by operation, in the interval's scale (:func:`_interval_scale`),
    exactly as the firmware's ``check_table`` (``firmware/src/calib.c``) checks it: a yes/no has no
    tolerance, and in double the two readers split on slopes within a rounding of the box's edge (the
    emulator took a set the firmware refused with ``CAL_BAD_SLOPE``, and refused sets the firmware took,
    so a board's set could not be read back)."""
    d = y[k + 1] - y[k]
    if (d <= 0.0) if rising else (d >= 0.0):
        raise CalibrationError(
            f"y goes {'down' if rising else 'up'} or stays ({y[k]!r} to {y[k + 1]!r}) in a"
            f" {'rising' if rising else 'falling'} table: not strictly monotone",
            f"y[{k + 1}]",
        )
    scale, secant, limit = _slope_box(k, x, y)
    for j in (k, k + 1):
        if (m[j] < 0.0 < secant) or (m[j] > 0.0 > secant) or f32(abs(m[j]) * scale) > limit:
            raise CalibrationError(
                f"slope {m[j]!r} is outside 0..3x the secant {d / (x[k + 1] - x[k])!r} of interval {k}: the"
                " cubic would not be monotone",
                f"slope[{j}]",
            )


def _slope_box(k: int, x: tuple[float, ...], y: tuple[float, ...]) -> tuple[float, float, float]:
    """(scale, secant, limit) of interval ``k`` as the firmware computes them, in float32: a knot slope
    ``m`` fits the interval's box when it has the secant's sign (any, if the secant underflowed to 0) and
    ``f32(|m|·scale) <= limit``. ``secant`` and ``limit`` are in the interval's scale; ``limit`` is 3× the
    secant with the readers' rounding slack."""
    scale = _interval_scale(y[k], y[k + 1])
    scaled = f32(f32(y[k + 1] * scale) - f32(y[k] * scale))
    secant = f32(scaled / f32(x[k + 1] - x[k]))
    return scale, secant, f32(f32(3.0 * abs(secant)) * _SLOPE_SLACK)


def _interval_scale(y0: float, y1: float) -> float:
    """The power of two the firmware takes an interval's values at (``calib.c``: ``interval_scale``):
    2^-64 when one lies beyond 2^64, 2^64 when both lie below 2^-64, else 1. Exact, so float32 arithmetic
    on the scaled values neither overflows nor loses a subnormal's bits."""
    top = max(abs(y0), abs(y1))
    return _SMALL_VALUE if top >= _BIG_VALUE else (_BIG_VALUE if top < _SMALL_VALUE else 1.0)


def _limit_slope(k: int, x: tuple[float, ...], y: tuple[float, ...], slope: float) -> float:
    """``slope`` rounded to float32 and, if rounding pushed it past 3× a neighbouring secant, stepped back.

    A slope beyond float32's range is taken at ±``F32_MAX``: knots close in x with values far apart (a
    secant of 1e39 rad/µs, a table spanning ±3e38) make PCHIP slopes no float32 holds, and rounding one
    raised a bare ``OverflowError`` (``hil calibrate show`` of such a file ended in a traceback). Any slope
    of the secants' sign up to 3× the smaller secant keeps the cubic monotone, so ``F32_MAX`` — below
    3× a secant that large — is as valid a knot slope as PCHIP's, and it is one the binary set stores.
    The slope is also kept inside the box as the readers check it in float32 (:func:`_slope_box`), which
    is tighter than 3× the secant only where that secant is a float32 subnormal.
    """
    limit = F32_MAX
    for j in (k - 1, k):
        if 0 <= j < len(x) - 1:
            scale, _, box = _slope_box(j, x, y)
            limit = min(limit, 3.0 * abs((y[j + 1] - y[j]) / (x[j + 1] - x[j])), box / scale)
    m = f32(math.copysign(min(abs(slope), limit), slope))
    while abs(m) > limit:
        m = _f32_toward_zero(m)
    return m


def _f32_toward_zero(v: float) -> float:
    """The float32 next to ``v`` (float32-exact, non-zero) in the direction of zero."""
    bits = _U32.unpack(struct.pack("<f", v))[0]
    return float(struct.unpack("<f", _U32.pack(bits - 1))[0])

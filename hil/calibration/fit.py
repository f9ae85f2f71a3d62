"""Fitting calibration maps to bench data: monotone cubic tables by least squares, then validation.

Each map is parametrised so that it is monotone by construction: knot values are a start value plus
non-negative increments (at least ``1e-4`` of the measured range each), so the table through them is
strictly monotone and PCHIP keeps it so between knots. ``scipy.optimize.least_squares`` fits the
parameters to every sample, evaluating the table with ``scipy.interpolate.PchipInterpolator`` (the same
interpolant the stored slopes describe). The rotor fit also finds where the ESC's deadband ends, the
gimbal-rate fit the edges of the servo's dead zone.

Validation, each failure a :class:`CalibrationError` naming the file (and lines where rows are at fault):
enough points; the pulse range covers the map (the ESC endpoints, both gimbal directions); endpoints sane
(the rotor is stopped at the ESC's low endpoint, the deadband is less than 30 % of the span, the speed
still rises at the high endpoint: an ESC taught other endpoints saturates early); every
interval between knots has data; and the data follows a monotone curve: no row lies further from the
fit than ``max(8 σ, 3 % of the range)``, σ the robust (MAD) noise estimate, and never further than
:data:`MAX_OFF_FRACTION` of the range whatever σ; the residuals' rms is at most :data:`MAX_RMS_FRACTION`
of the range. (σ is the fit's own: for data that follows no monotone curve — random, shuffled, folded,
wrapped, rows of one pulse in conflict — it is as large as the data, and the first test alone passed it.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import least_squares

from protocol.calibration import EscThrottleMap, GimbalAngleMap, GimbalRateMap, MonotoneCubic, RotorSpeedMap
from protocol.calibration.checks import within
from protocol.errors import CalibrationError, ConvergenceError

from .bench import BenchData, BenchKind

MIN_POINTS = 20
MIN_INCREMENT = 1e-4  # of the measured range, per knot interval
OUTLIER_SIGMAS = 8.0
OUTLIER_FRACTION_OF_RANGE = 0.03
MAX_OFF_FRACTION = 0.10
MAX_RMS_FRACTION = 0.03
"""No row further from the best monotone fit than 10 % of the range, and a residual rms of at most 3 % of
it, however noisy the data says it is. Chosen by a stated procedure: the largest values over every sweep
the repository has — the committed fixtures, ``hil calibrate bench`` for seeds 0..39 (4 units each), the
emulator's sweeps of dispersed units (``unit_spread`` 3 and 7, 4 units, default steps) — are 2.2 % (a
row, a generated gimbal-rate sweep) and 0.62 % (rms, the same), so the bounds leave 4.6x and 4.8x of
margin; data that follows no monotone curve (uniform random values, values shuffled, a curve folded back
or wrapped, every row repeated at half its value) leaves 33-120 % and 19-70 %. The range (the scale) is
full speed ``KV·V`` for a rotor, the fastest rate for a gimbal, the angle's span for an angle."""
MIN_MOTION = 1e-3
"""Below this a sweep saw nothing move: a gimbal's fastest rate (rad/s) or its angle's span (rad); a
rotor's fastest speed, a thousand times it (1 rad/s, 10 rpm). The fits' other tests are relative to the
sweep's own top, so without it a sweep of a servo that never moved (rates of 1e-300 rad/s) was fitted."""
STOPPED_FRACTION = 0.03  # a rotor below 3 % of its top speed (or gimbal below 3 % of its top rate) is still
TOP_FRACTION = 0.03  # the top rows of a rotor sweep: the last 3 % of the endpoint span ...
TOP_RISE = 0.01  # ... must be at least 1 % of full speed faster than the rows 6-12 % below the top
END_FRACTION = 0.1
"""The rows of a gimbal-angle sweep within this fraction of its pulse span of either end ..."""
END_SLOPE = 0.4
"""... must still turn the angle at least this fraction of the sweep's mean slope (span of the angle over
span of the pulses), fitted by a line through them: a servo driven against its stop, or an angle sensor
that saturates, reads a flat end, which the fit took as a table rising by its minimum increments there
(``MIN_INCREMENT``), so a command near that angle put the servo anywhere on the plateau — against its stop.
Chosen by a stated procedure: the smallest value over every angle sweep the repository has (the committed
fixtures, ``hil calibrate bench`` for seeds 0..39, 4 units each, the emulator's sweeps of dispersed units)
is 1.00 (346 ends), so the bound leaves 2.5x of margin; a flat end reads 0."""

RATE_END_SLOPE = 0.2
"""A gimbal-rate sweep's end saturates where the rows within :data:`END_FRACTION` of its side's pulse span
(from the sweep's middle) grow the rate less than this fraction of the side's mean slope (its top rate over
that span), fitted by a line. Lower than :data:`END_SLOPE`: the mean counts the dead zone, and a rate is
noisier than an angle. Chosen by a stated procedure: the smallest value over every rate sweep the
repository has (the committed fixtures, ``hil calibrate bench`` for seeds 0..39, 4 units each; 328 ends)
is 0.48, so the bound leaves 2.4x of margin; a saturated end reads 0."""


@dataclass(frozen=True)
class FitOptions:
    """Fitting choices. ESC endpoints are those the ESC was calibrated to (its high/low procedure)."""

    esc_low_us: float = 1000.0
    esc_high_us: float = 2000.0
    rotor_knots: int = 9
    gimbal_rate_knots_per_side: int = 6
    gimbal_angle_knots: int = 9

    def __post_init__(self) -> None:
        # whole numbers only: 3.5 knots passed here and the fit failed later with numpy's bare TypeError,
        # "x" or None failed here with Python's
        for name, most in (
            ("rotor_knots", 16),
            ("gimbal_rate_knots_per_side", 8),
            ("gimbal_angle_knots", 16),
        ):
            knots = getattr(self, name)
            if isinstance(knots, bool) or not isinstance(knots, int | np.integer) or not 3 <= knots <= most:
                raise CalibrationError(f"{knots!r}; need a whole number 3..{most}", f"FitOptions.{name}")
            object.__setattr__(self, name, int(knots))
        with within("FitOptions"):
            EscThrottleMap(self.esc_low_us, self.esc_high_us, 0.0)


@dataclass(frozen=True)
class FitReport:
    """How well a map fits its data. ``residuals`` (n,) = measured − fitted, in ``unit`` (rad/s or rad)."""

    kind: BenchKind
    source: str
    unit: str
    residuals: np.ndarray
    lines: np.ndarray
    knots: int
    battery_v: tuple[float, float] | None = None
    notes: tuple[str, ...] = field(default=())
    """What the fit did beyond fitting every row (a gimbal rate's saturated ends left out), said by
    :meth:`summary`."""

    @property
    def points(self) -> int:
        return len(self.residuals)

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.residuals)))

    @property
    def worst_line(self) -> int:
        return int(self.lines[int(np.argmax(np.abs(self.residuals)))])

    def summary(self) -> str:
        v = f", battery {self.battery_v[0]:.2f}-{self.battery_v[1]:.2f} V" if self.battery_v else ""
        said = "".join(f"\n  note: {note}" for note in self.notes)  # rows the fit left out, and why
        return (
            f"{self.kind.value:<12} {self.points:4d} points, {self.knots:2d} knots: residual rms"
            f" {self.rms:.4g} {self.unit}, max {self.max_abs:.4g} {self.unit} (line {self.worst_line}){v}"
        ) + said


@dataclass(frozen=True)
class Fit:
    """A fitted map (``RotorSpeedMap``, ``GimbalRateMap`` or ``GimbalAngleMap``) and its report."""

    map: RotorSpeedMap | GimbalRateMap | GimbalAngleMap
    report: FitReport


def fit_bench(data: BenchData, options: FitOptions | None = None) -> Fit:
    """Fit the map ``data`` measures (by its kind)."""
    opts = options or FitOptions()
    if data.kind is BenchKind.ROTOR:
        return fit_rotor(data, opts)
    if data.kind is BenchKind.GIMBAL_RATE:
        return fit_gimbal_rate(data, opts)
    return fit_gimbal_angle(data, opts)


# =========================================================================== rotor
def fit_rotor(data: BenchData, opts: FitOptions) -> Fit:
    """ESC deadband, KV and the throttle curve f from (pulse, battery V, speed) samples."""
    p, v, w = data.pulse_us, data.battery_v, data.value
    n_knots = opts.rotor_knots
    low, high = opts.esc_low_us, opts.esc_high_us
    span = high - low
    _require_points(data, max(MIN_POINTS, 3 * n_knots))
    if p.min() > low + 0.02 * span or p.max() < high - 0.02 * span:
        raise CalibrationError(
            f"pulses {p.min():g}-{p.max():g} µs do not cover the ESC endpoints {low:g}-{high:g} µs"
            " (sweep from the low to the high endpoint)",
            data.path,
        )
    z = w / v  # rad/s per volt
    z_top = float(z.max())
    if float(w.max()) < MIN_MOTION * 1_000.0:
        raise CalibrationError(f"the rotor never turned (its fastest: {float(w.max()):.3g} rad/s)", data.path)
    stopped = z <= STOPPED_FRACTION * z_top
    turning_at_low = np.nonzero((p <= low) & ~stopped)[0]
    if turning_at_low.size:
        raise CalibrationError(
            f"the rotor turns at or below the low endpoint {low:g} µs ({data.rows(turning_at_low)}):"
            " the ESC is not calibrated to that endpoint (recalibrate it, or give its real low endpoint)",
            data.path,
        )
    p_run = float(p[~stopped].min())
    below = p[stopped & (p < p_run)]
    start0 = 0.5 * (float(below.max()) + p_run) if below.size else p_run
    start_max = low + 0.3 * span
    if start0 > start_max:
        raise CalibrationError(
            f"the rotor only starts at {p_run:g} µs: a deadband over 30 % of the endpoint span is not an ESC"
            " calibrated to these endpoints",
            data.path,
        )
    _require_rising_top(data, p, z, low, high, z_top)
    taus = np.linspace(0.0, 1.0, n_knots)
    eps = MIN_INCREMENT * z_top

    def knots(theta: np.ndarray) -> tuple[float, np.ndarray]:
        return float(theta[0]), np.concatenate(([0.0], np.cumsum(theta[1:])))

    def throttle(start: float) -> np.ndarray:
        return np.clip((p - start) / (high - start), 0.0, 1.0)

    def residuals(theta: np.ndarray) -> np.ndarray:
        start, g = knots(theta)
        return v * PchipInterpolator(taus, g)(throttle(start)) - w

    g0 = _monotone_guess(throttle(start0), z, taus, eps, first=0.0)
    theta0 = np.concatenate(([start0], np.diff(g0)))
    lb = np.concatenate(([low], np.full(n_knots - 1, eps)))
    ub = np.concatenate(([start_max], np.full(n_knots - 1, np.inf)))
    theta = _least_squares(residuals, theta0, lb, ub, data.path)
    start, g = knots(theta)
    _require_coverage(data, throttle(start), taus, ~stopped | (p > start), "throttle")
    kv = float(g[-1])
    with within(data.path):
        rotor = RotorSpeedMap(
            EscThrottleMap(low, high, start - low), kv, MonotoneCubic.pchip(taus.tolist(), (g / kv).tolist())
        )
    fitted = np.array([rotor.speed(pi, vi).value for pi, vi in zip(p, v, strict=True)])
    report = _report(data, fitted, "rad/s", kv * float(v.max()), n_knots)
    return Fit(rotor, report)


def _require_rising_top(
    data: BenchData, p: np.ndarray, z: np.ndarray, low: float, high: float, z_top: float
) -> None:
    """The speed (per volt) must still rise over the last tenth of the span: an ESC whose own high
    endpoint lies below ``high`` reaches full throttle early and stays there (a flat top the table would
    absorb as a slow last interval)."""
    span = high - low
    top = p >= high - TOP_FRACTION * span
    below = (p >= high - 4 * TOP_FRACTION * span) & (p < high - 2 * TOP_FRACTION * span)
    if not (top.any() and below.any()):
        return
    rise = float(z[top].mean() - z[below].mean())
    if rise < TOP_RISE * z_top:
        flat = np.nonzero(p >= high - 2 * TOP_FRACTION * span)[0]
        raise CalibrationError(
            f"the rotor speed stops rising before the high endpoint {high:g} µs ({data.rows(flat)} gain "
            f"{100 * rise / z_top:.2g} % of full speed over the last {4 * TOP_FRACTION * span:g} µs): the ESC"
            " is not calibrated to these endpoints (teach it them: hil calibrate esc; or give its real high"
            " endpoint)",
            data.path,
        )


# =========================================================================== gimbal rate
def fit_gimbal_rate(data: BenchData, opts: FitOptions) -> Fit:
    """Dead zone edges and the rate table each side of it from (pulse, rate) samples.

    A continuous servo's rate saturates by design: where its rate stops growing at an end of the sweep
    (:func:`_saturated_rows`) those rows are kept out of the fit and said in the report's notes, and the
    table ends where the rate reached its top (a pulse past it is clamped there). Fitted as if the rate grew,
    the table rose by its minimum increments over the plateau, so a rate near the top was commanded
    anywhere on it. The report's residuals are over every row, the saturated ones against that clamp."""
    n = opts.gimbal_rate_knots_per_side
    _require_points(data, max(MIN_POINTS, 4 * n))
    p_all = data.pulse_us
    reach_all = float(p_all.max() - p_all.min())
    if reach_all < 200.0:
        raise CalibrationError(f"pulses only span {reach_all:g} µs; sweep the servo's whole range", data.path)
    s = _direction(p_all, data.value)
    r_all = s * data.value  # rising in pulse
    r_top = float(np.abs(r_all).max())
    if r_top < MIN_MOTION:
        raise CalibrationError(f"the gimbal never turned (its fastest: {r_top:.3g} rad/s)", data.path)
    kept, notes = _saturated_rows(data, p_all, r_all, r_top, s)
    p, r = p_all[kept], r_all[kept]
    p_min, p_max = float(p.min()), float(p.max())
    reach = p_max - p_min
    moving = np.abs(r) > STOPPED_FRACTION * r_top
    neg, pos = moving & (r < 0), moving & (r > 0)
    if neg.sum() < 3 or pos.sum() < 3:
        raise CalibrationError(
            f"{int(neg.sum())} samples turning one way and {int(pos.sum())} the other: need 3+ each way",
            data.path,
        )
    still = ~moving
    center = float(np.median(p[still])) if still.any() else 0.5 * (float(p[neg].max()) + float(p[pos].min()))
    last_neg = float(p[neg & (p < center)].max(initial=p_min))
    first_pos = float(p[pos & (p > center)].min(initial=p_max))
    still_band = p[still & (p > last_neg) & (p < first_pos)]
    if still_band.size:
        e_lo0 = 0.5 * (last_neg + float(still_band.min()))
        e_hi0 = 0.5 * (float(still_band.max()) + first_pos)
    else:
        e_lo0 = e_hi0 = 0.5 * (last_neg + first_pos)
    # the dead zone lies near the middle of the whole sweep, not of the part fitted (a saturated end left
    # out moves that part's middle: bounds from it excluded the dead zone, and the fit failed)
    lo_bounds = (p_min + 0.05 * reach, float(p_all.min()) + 0.6 * reach_all)
    w_bounds = (0.5, 0.3 * reach_all)
    e_lo0 = float(np.clip(e_lo0, *lo_bounds))
    width0 = float(np.clip(e_hi0 - e_lo0, w_bounds[0] * 1.01, w_bounds[1] * 0.99))
    eps = MIN_INCREMENT * r_top

    def sides(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Knots (x, y) below and above the dead zone [theta[0], theta[0] + theta[1]]."""
        e_lo, e_hi = float(theta[0]), float(theta[0] + theta[1])
        lower_y = np.concatenate((-np.cumsum(theta[2 : n + 1][::-1])[::-1], [0.0]))
        upper_y = np.concatenate(([0.0], np.cumsum(theta[n + 1 :])))
        return np.linspace(p_min, e_lo, n), lower_y, np.linspace(e_hi, p_max, n), upper_y

    def residuals(theta: np.ndarray) -> np.ndarray:
        lx, ly, ux, uy = sides(theta)
        out = np.zeros_like(p)
        below, above = p < lx[-1], p > ux[0]
        out[below] = PchipInterpolator(lx, ly)(p[below])
        out[above] = PchipInterpolator(ux, uy)(p[above])
        return out - r

    lower0 = _monotone_guess(p, r, np.linspace(p_min, e_lo0, n), eps, last=0.0)
    upper0 = _monotone_guess(p, r, np.linspace(e_lo0 + width0, p_max, n), eps, first=0.0)
    theta0 = np.concatenate(([e_lo0, width0], np.diff(lower0), np.diff(upper0)))
    lb = np.concatenate(([lo_bounds[0], w_bounds[0]], np.full(2 * (n - 1), eps)))
    ub = np.concatenate(([lo_bounds[1], w_bounds[1]], np.full(2 * (n - 1), np.inf)))
    theta = _least_squares(residuals, theta0, lb, ub, data.path)
    lx, ly, ux, uy = sides(theta)
    _require_coverage(data, p, lx, p <= lx[-1], "pulse")
    _require_coverage(data, p, ux, p >= ux[0], "pulse")
    with within(data.path):
        rate = GimbalRateMap(
            0.5 * (lx[-1] + ux[0]),
            MonotoneCubic.pchip(lx.tolist(), (s * ly).tolist()),
            MonotoneCubic.pchip(ux.tolist(), (s * uy).tolist()),
        )
    fitted = np.array([rate.rate(pi).value for pi in p_all])
    return Fit(rate, replace(_report(data, fitted, "rad/s", r_top, 2 * n), notes=notes))


def _saturated_rows(
    data: BenchData, p: np.ndarray, r: np.ndarray, r_top: float, s: float
) -> tuple[np.ndarray, tuple[str, ...]]:
    """The rows of a gimbal-rate sweep to fit (a mask) and a note for each end left out.

    ``r`` (rad/s) is the rate made rising in pulse (``s`` the sign that made it so). An end whose rate
    stops growing — a line through the rows within :data:`END_FRACTION` of that side's pulse span from the
    sweep's middle (at least its last three pulses) grows less than :data:`RATE_END_SLOPE` of the side's
    mean slope, as :func:`_require_moving_ends` tests an angle — is left out from the first pulse whose rate,
    and every one's beyond it, is within the plateau's noise (3 σ, at least 0.5 % of the top rate) of the
    plateau's level. That pulse itself is kept: the table then ends where the rate reached its top."""
    kept = np.ones(len(p), dtype=bool)
    notes: list[str] = []
    middle = 0.5 * (float(p.min()) + float(p.max()))
    for name, side in (("low", p < middle), ("high", p > middle)):
        sign = -1.0 if name == "low" else 1.0  # the rate grows away from the middle: -r below it, r above
        if side.sum() < 3:
            continue
        end = float(p[side].min()) if name == "low" else float(p[side].max())
        outward = sign * (p[side] - middle)  # µs from the middle, towards the end
        grown = sign * r[side]  # rad/s, growing towards the end
        reach = float(outward.max())  # µs from the middle to the end
        steps = np.unique(outward)
        if steps.size < 3 or float(grown.max()) <= 0.0:  # no slope to tell; never turned so: refused later
            continue
        # the last END_FRACTION of the side, or its last three pulses if wider (a coarse sweep: fewer
        # pulses there could not tell a slope from noise, and a saturated end was fitted as if it grew)
        window = outward >= min(reach - END_FRACTION * reach, float(steps[-3]))
        mean_slope = float(grown.max()) / reach  # rad/s per µs, from the middle (rate ~0) out
        if float(np.polyfit(outward[window], grown[window], 1)[0]) >= RATE_END_SLOPE * mean_slope:
            continue
        plateau = grown[window]
        level = float(np.median(plateau))
        noise = 1.4826 * float(np.median(np.abs(plateau - level)))
        floor = level - max(3.0 * noise, 0.005 * r_top)
        below = outward[grown < floor]  # rows short of the plateau: the fit keeps up to the first past them
        reached = outward[(grown >= floor) & (outward > (float(below.max()) if below.size else -np.inf))]
        if not reached.size:  # the last row is short of the plateau's level: no plateau to leave out
            continue
        start = float(reached.min())
        left_out = np.nonzero(side)[0][outward > start]
        if not left_out.size:
            continue
        kept[left_out] = False
        start_us = middle + sign * start
        notes.append(
            f"the rate stops growing at {start_us:g} µs ({sign * s * level:.4g} rad/s): the servo"
            f" saturates at the {name} end; {left_out.size} rows ({data.rows(left_out)},"
            f" to {end:g} µs) left out of the fit, the map ends at {start_us:g} µs"
        )
    return kept, tuple(notes)


# =========================================================================== gimbal angle
def fit_gimbal_angle(data: BenchData, opts: FitOptions) -> Fit:
    """The angle table from (pulse, angle) samples."""
    p = data.pulse_us
    n = opts.gimbal_angle_knots
    _require_points(data, max(MIN_POINTS, 2 * n))
    p_min, p_max = float(p.min()), float(p.max())
    if p_max - p_min < 200.0:
        raise CalibrationError(f"pulses only span {p_max - p_min:g} µs; sweep the servo's range", data.path)
    s = _direction(p, data.value)
    a = s * data.value
    a_span = float(a.max() - a.min())
    if a_span < MIN_MOTION:
        raise CalibrationError(f"the angle never changes (it spans {a_span:.3g} rad)", data.path)
    xs = np.linspace(p_min, p_max, n)
    eps = MIN_INCREMENT * a_span

    def residuals(theta: np.ndarray) -> np.ndarray:
        return PchipInterpolator(xs, theta[0] + np.concatenate(([0.0], np.cumsum(theta[1:]))))(p) - a

    y0 = _monotone_guess(p, a, xs, eps)
    theta0 = np.concatenate(([y0[0]], np.diff(y0)))
    lb = np.concatenate(([-np.inf], np.full(n - 1, eps)))
    theta = _least_squares(residuals, theta0, lb, np.full(n, np.inf), data.path)
    ys = theta[0] + np.concatenate(([0.0], np.cumsum(theta[1:])))
    _require_coverage(data, p, xs, np.ones(len(p), dtype=bool), "pulse")
    with within(data.path):
        angle = GimbalAngleMap(MonotoneCubic.pchip(xs.tolist(), (s * ys).tolist()))
    fitted = np.array([angle.angle(pi).value for pi in p])
    report = _report(data, fitted, "rad", a_span, n)  # outliers, data on no monotone curve: said first
    _require_moving_ends(data, p, a, a_span)
    return Fit(angle, report)


def _require_moving_ends(data: BenchData, p: np.ndarray, a: np.ndarray, a_span: float) -> None:
    """The angle (``a``, rad, rising in pulse) must still change at both ends of the sweep
    (:data:`END_FRACTION`, :data:`END_SLOPE`): a flat end is a servo at its stop or a saturated sensor,
    never a map (the rotor's flat top is refused so too: :func:`_require_rising_top`)."""
    p_min, p_max = float(p.min()), float(p.max())
    reach = p_max - p_min
    mean_slope = a_span / reach  # rad/µs
    window = END_FRACTION * reach
    for name, rows in (("low", p <= p_min + window), ("high", p >= p_max - window)):
        if np.unique(p[rows]).size < 3:  # too few pulses there to tell a slope from noise
            continue
        slope = float(np.polyfit(p[rows], a[rows], 1)[0])
        if slope < END_SLOPE * mean_slope:
            end = p_min if name == "low" else p_max
            how = "turns back" if slope < 0 else "stops changing"
            share = 100 * slope / mean_slope
            raise CalibrationError(
                f"the angle {how} at the {name} end of the sweep ({data.rows(np.nonzero(rows)[0])}:"
                f" {slope:.3g} rad/µs over the {window:g} µs up to {end:g} µs, {share:.2g} % of the"
                f" sweep's mean {mean_slope:.3g} rad/µs): the servo reached a stop, or the angle sensor"
                " saturates; sweep within the servo's travel (hil calibrate sweep --range)",
                data.path,
            )


# =========================================================================== shared steps
def _require_points(data: BenchData, need: int) -> None:
    if len(data) < need:
        raise CalibrationError(f"{len(data)} data rows; this fit needs at least {need}", data.path)


def _direction(p: np.ndarray, y: np.ndarray) -> float:
    """+1 if ``y`` grows with pulse (compare the top and bottom thirds of the pulses), else -1."""
    order = np.argsort(p, kind="stable")
    third = max(1, len(p) // 3)
    return 1.0 if y[order[-third:]].mean() >= y[order[:third]].mean() else -1.0


def _monotone_guess(
    x: np.ndarray,
    y: np.ndarray,
    knots_x: np.ndarray,
    eps: float,
    first: float | None = None,
    last: float | None = None,
) -> np.ndarray:
    """Increasing start values at ``knots_x``: the median of ``y`` near each knot, made monotone with at
    least ``eps`` per step, with the first (or last) value pinned if given."""
    half = 0.5 * float(np.min(np.diff(knots_x)))
    order = np.argsort(x)
    values = np.empty(len(knots_x))
    for j, k in enumerate(knots_x):
        near = np.abs(x - k) <= half
        values[j] = np.median(y[near]) if near.any() else np.interp(k, x[order], y[order])
    if last is not None:
        values[-1] = last
        for j in range(len(values) - 2, -1, -1):
            values[j] = min(values[j], values[j + 1] - eps)
        return values
    if first is not None:
        values[0] = first
    for j in range(1, len(values)):
        values[j] = max(values[j], values[j - 1] + eps)
    return values


def _least_squares(fun: Callable[[np.ndarray], np.ndarray], theta0, lb, ub, path: str) -> np.ndarray:
    theta0 = np.clip(theta0, lb, ub)
    try:
        result = least_squares(fun, theta0, bounds=(lb, ub), x_scale="jac", max_nfev=2000)
    except ValueError as exc:  # residuals that overflowed to inf or NaN: no fit, said so
        raise ConvergenceError(f"{path}: the fit did not converge ({exc})") from None
    if result.status <= 0:
        raise ConvergenceError(f"{path}: the fit did not converge ({result.message})")
    return np.asarray(result.x)


def _require_coverage(
    data: BenchData, x: np.ndarray, knots_x: np.ndarray, mask: np.ndarray, axis: str
) -> None:
    """Every interval between consecutive knots must hold at least one (masked) sample."""
    xm = x[mask]
    for a, b in zip(knots_x[:-1], knots_x[1:], strict=True):
        if not np.any((xm >= a) & (xm <= b)):
            raise CalibrationError(
                f"no samples between {axis} {a:.4g} and {b:.4g}: the sweep has a gap (or use fewer knots)",
                data.path,
            )


def _report(data: BenchData, fitted: np.ndarray, unit: str, scale: float, knots: int) -> FitReport:
    """The fit's residuals; :class:`CalibrationError` naming the rows if the data is not a monotone curve
    (rows off it: :data:`OUTLIER_SIGMAS`, :data:`OUTLIER_FRACTION_OF_RANGE`, :data:`MAX_OFF_FRACTION`; all
    of it: :data:`MAX_RMS_FRACTION`), ``scale`` the range (rad/s or rad)."""
    resid = data.value - fitted
    sigma = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    limit = min(max(OUTLIER_SIGMAS * sigma, OUTLIER_FRACTION_OF_RANGE * scale), MAX_OFF_FRACTION * scale)
    off = np.nonzero(np.abs(resid) > limit)[0]
    if off.size:
        off = off[np.argsort(-np.abs(resid[off]))]
        raise CalibrationError(
            f"{data.rows(off)} lie up to {float(np.abs(resid[off]).max()):.4g} {unit} off the best"
            f" monotone fit (noise ~{sigma:.3g} {unit}, limit {limit:.3g}): the data is not monotone in"
            " pulse, or has outliers",
            data.path,
        )
    rms = float(np.sqrt(np.mean(resid**2)))
    if rms > MAX_RMS_FRACTION * scale:
        raise CalibrationError(
            f"the data does not follow a monotone curve in pulse: the best monotone fit leaves residuals of"
            f" {rms:.4g} {unit} rms, {100 * rms / scale:.3g} % of the range {scale:.4g} {unit} (at most"
            f" {100 * MAX_RMS_FRACTION:g} %; a sweep's noise leaves under 1 %): values random, shuffled,"
            " folded back, wrapped, or in conflict where a pulse repeats",
            data.path,
        )
    battery = data.battery_v[np.isfinite(data.battery_v)]
    vrange = (
        (float(battery.min()), float(battery.max()))
        if battery.size and data.kind is BenchKind.ROTOR
        else None
    )
    return FitReport(data.kind, data.path, unit, resid, data.lines, knots, vrange)

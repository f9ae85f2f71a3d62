"""The calibration maps of one VSCMG unit, each with its inverse. Every map clamps an input outside its
range to the range's nearest end and says so (:class:`Conversion`).

Rotor (ESC + BLDC motor), two maps in series::

    pulse µs ──EscThrottleMap──► throttle τ ∈ [0, 1] ──RotorSpeedMap──► no-load speed ω = KV·V·f(τ) rad/s

* ``EscThrottleMap``: the ESC after its high/low endpoint calibration. ``low_us`` is the calibrated low
  endpoint, the minimum-throttle pulse the ESC arms on; pulses up to ``low_us + deadband_us`` still mean
  throttle 0 (motor off); throttle then rises linearly to 1 at ``high_us``, the calibrated high endpoint.
* ``RotorSpeedMap``: ``f`` is a monotone table over τ with f(0) = 0 and f(1) = 1, so ``KV·V`` is the
  full-throttle no-load speed at battery voltage ``V`` (rad/s per volt: KV in rpm/V × π/30).

Gimbal (servo or stepper driver on the same channel), one map per ``GimbalMode``:

* ``GimbalRateMap`` (RATE): rate 0 in the servo's dead zone between the ``lower`` table's last pulse and
  the ``upper`` table's first pulse, each table a strictly monotone pulse µs → rate rad/s curve that is 0
  at its dead-zone end (so the curve may leave the dead zone with a kink, as a servo does);
  ``hold_us`` (inside the dead zone) is the pulse that holds the gimbal still.
* ``GimbalAngleMap`` (ANGLE): a strictly monotone table pulse µs → angle rad.

Every pulse a map holds — the ESC's endpoints, the gimbal tables' knots, the hold pulse — lies within the
protocol's ``PULSE_MIN_US..PULSE_MAX_US`` (500..2500 µs). A conversion clamps to its table's ends, so then
every width a map commands is one a board can put out. A map beyond that range used to be taken (from a
file, in an upload) and the board clamped its widths instead: a hold pulse at 10000 µs became 2500 µs, the
gimbal turning at full rate under a rate-0 command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import CalibrationError, FieldRangeError
from ..messages import PULSE_MAX_US, PULSE_MIN_US
from .checks import f32, finite32, require_finite
from .conversion import Clamp, Conversion
from .cubic import MonotoneCubic

MIN_SUPPLY_V = 1.0
"""Below this battery voltage there is no usable supply: speed 0, and any positive speed command gets the
minimum-throttle pulse (flagged HIGH: the speed is out of reach)."""
MAX_KV_RAD_S_PER_V = 1.0e4


def check_pulses(pulses: tuple[float, ...], where: str) -> None:
    """:class:`CalibrationError` at ``where[k]`` for the first pulse (µs) of a map's table outside the
    protocol's ``PULSE_MIN_US..PULSE_MAX_US``: a board cannot put it out (see the module docstring)."""
    for k, p in enumerate(pulses):
        check_pulse(p, f"{where}[{k}]")


def check_pulse(pulse_us: float, where: str) -> None:
    """:class:`CalibrationError` at ``where`` if ``pulse_us`` lies outside ``PULSE_MIN_US..PULSE_MAX_US``."""
    if not PULSE_MIN_US <= pulse_us <= PULSE_MAX_US:
        span = f"{PULSE_MIN_US}..{PULSE_MAX_US} µs"
        raise CalibrationError(f"{pulse_us:g} µs is outside the pulses a board puts out, {span}", where)


@dataclass(frozen=True, slots=True)
class EscThrottleMap:
    """Pulse width (µs) ↔ normalised throttle of an ESC calibrated to ``low_us``/``high_us``."""

    low_us: float = 1000.0
    high_us: float = 2000.0
    deadband_us: float = 0.0

    def __post_init__(self) -> None:
        low = finite32(self.low_us, "low_us")
        high = finite32(self.high_us, "high_us")
        dead = finite32(self.deadband_us, "deadband_us")
        if not PULSE_MIN_US <= low < high <= PULSE_MAX_US:
            raise CalibrationError(
                f"need {PULSE_MIN_US} <= low_us < high_us <= {PULSE_MAX_US} µs (got {low:g}, {high:g})",
                "low_us",
            )
        # Half the span as the firmware's cal_validate computes it, in float32 (``high - low`` rounded):
        # in double a deadband within a rounding of half the span passed here and was refused by the board
        # (NACK BAD_CALIBRATION for a set ``hil calibrate show`` called valid).
        half_span = 0.5 * f32(high - low)
        if not 0.0 <= dead < half_span:
            raise CalibrationError(
                f"{dead:.9g} µs; need 0 <= deadband_us < half the endpoint span ({half_span:.9g} µs)",
                "deadband_us",
            )
        object.__setattr__(self, "low_us", low)
        object.__setattr__(self, "high_us", high)
        object.__setattr__(self, "deadband_us", dead)

    @property
    def start_us(self) -> float:
        """The pulse at which throttle starts to rise above 0 (end of the deadband)."""
        return self.low_us + self.deadband_us

    def throttle(self, pulse_us: float) -> Conversion:
        """Throttle 0..1 of ``pulse_us``; below ``low_us`` or above ``high_us`` it is clamped and flagged."""
        p = require_finite(pulse_us, "EscThrottleMap.throttle", "pulse_us")
        if p < self.low_us:
            return Conversion(0.0, Clamp.LOW)
        if p > self.high_us:
            return Conversion(1.0, Clamp.HIGH)
        start = self.start_us
        if p <= start:
            return Conversion(0.0)
        return Conversion((p - start) / (self.high_us - start))

    def pulse(self, throttle: float) -> Conversion:
        """The pulse for ``throttle``: 0 is ``low_us`` (minimum throttle, the arming pulse), a throttle just
        above 0 starts at the deadband's end; outside 0..1 it is clamped and flagged."""
        tau = require_finite(throttle, "EscThrottleMap.pulse", "throttle")
        if tau <= 0.0:
            return Conversion(self.low_us, Clamp.LOW if tau < 0.0 else Clamp.NONE)
        if tau >= 1.0:
            return Conversion(self.high_us, Clamp.HIGH if tau > 1.0 else Clamp.NONE)
        start = self.start_us
        return Conversion(start + tau * (self.high_us - start))


@dataclass(frozen=True, slots=True)
class RotorSpeedMap:
    """Pulse (µs) and battery voltage (V) ↔ steady no-load rotor speed (rad/s): ω = KV·V·f(τ(pulse))."""

    esc: EscThrottleMap
    kv_rad_s_per_v: float
    curve: MonotoneCubic  # τ → f(τ): x from 0 to 1, y from 0 to 1, strictly increasing

    def __post_init__(self) -> None:
        kv = finite32(self.kv_rad_s_per_v, "kv_rad_s_per_v")
        if not 0.0 < kv <= MAX_KV_RAD_S_PER_V:
            raise CalibrationError(f"{kv:g} rad/s/V; need 0 < KV <= {MAX_KV_RAD_S_PER_V:g}", "kv_rad_s_per_v")
        object.__setattr__(self, "kv_rad_s_per_v", kv)
        c = self.curve
        if c.x_range != (0.0, 1.0) or (c.y[0], c.y[-1]) != (0.0, 1.0):
            raise CalibrationError(
                f"throttle curve must run from (0, 0) to (1, 1), got ({c.x[0]:g}, {c.y[0]:g}) to "
                f"({c.x[-1]:g}, {c.y[-1]:g})",
                "curve",
            )

    def full_speed(self, battery_v: float) -> float:
        """No-load speed at full throttle (rad/s) at ``battery_v`` (V): 0 below :data:`MIN_SUPPLY_V`.
        :class:`~protocol.errors.FieldRangeError` for a ``battery_v`` that is no finite number (NaN read as
        no supply, 0 rad/s) or at which ``KV·V`` is beyond a float (see :meth:`_full_speed_at`)."""
        v = require_finite(battery_v, "RotorSpeedMap.full_speed", "battery_v")
        return self._full_speed_at(v, "RotorSpeedMap.full_speed") if v >= MIN_SUPPLY_V else 0.0

    def speed(self, pulse_us: float, battery_v: float) -> Conversion:
        """Steady no-load speed (rad/s) of ``pulse_us`` at ``battery_v`` (V); below :data:`MIN_SUPPLY_V`
        0, flagged LOW. :class:`~protocol.errors.FieldRangeError` for a voltage at which the full-throttle
        speed ``KV·V`` is beyond a float (see :meth:`_full_speed_at`)."""
        v = require_finite(battery_v, "RotorSpeedMap.speed", "battery_v")
        tau = self.esc.throttle(pulse_us)
        if v < MIN_SUPPLY_V:
            return Conversion(0.0, Clamp.LOW)
        full = self._full_speed_at(v, "RotorSpeedMap.speed")
        frac = self.curve.evaluate(tau.value).value
        return Conversion(full * frac, tau.clamp)

    def _full_speed_at(self, battery_v: float, what: str) -> float:
        """``KV·V`` (rad/s) at a finite ``battery_v`` of at least :data:`MIN_SUPPLY_V`, or
        :class:`~protocol.errors.FieldRangeError` naming ``what.battery_v`` where that product is beyond a
        float (V above ~1.8e308 / KV, 1.8e304 V at the largest KV): no speed can be said there. The
        product overflowed to inf, and ``speed`` gave inf, unflagged, at any throttle above 0 and NaN at
        throttle 0 (inf · 0), where a rotor that is off turns at 0 rad/s at every voltage. (:meth:`pulse`
        answers at any finite voltage: its answer is a pulse within the ESC's endpoints.)"""
        full = self.kv_rad_s_per_v * battery_v
        if full == math.inf:
            raise FieldRangeError(what, "battery_v", battery_v)
        return full

    def pulse(self, speed_rad_s: float, battery_v: float) -> Conversion:
        """The pulse (µs) whose steady no-load speed at ``battery_v`` is ``speed_rad_s``. Speed 0 is the
        minimum-throttle pulse; a negative speed (the ESC cannot reverse) or one above full speed is
        clamped and flagged.

        Any positive speed gets a throttle above 0, at least the deadband's end (``esc.start_us``), never
        the arming pulse ``low_us`` that stops the motor (the firmware's ``cal_rotor_pulse_us`` does the
        same). A fraction ``speed / (KV·V)`` that underflows to 0 (a speed of 1e-320 rad/s), and a
        full-throttle speed ``KV·V`` that overflows to inf (a battery reading of 1e308 V, which made the
        fraction 0), both gave ``low_us``, unflagged, for a rotor asked to turn."""
        w = require_finite(speed_rad_s, "RotorSpeedMap.pulse", "speed_rad_s")
        v = require_finite(battery_v, "RotorSpeedMap.pulse", "battery_v")
        esc = self.esc
        if w <= 0.0:
            return Conversion(esc.low_us, Clamp.LOW if w < 0.0 else Clamp.NONE)
        if v < MIN_SUPPLY_V:
            return Conversion(esc.low_us, Clamp.HIGH)
        full = self.kv_rad_s_per_v * v  # rad/s at full throttle
        phi = w / full if full < math.inf else w / self.kv_rad_s_per_v / v
        if phi >= 1.0:
            return Conversion(esc.high_us, Clamp.HIGH if phi > 1.0 else Clamp.NONE)
        tau = self.curve.solve(phi).value if phi > 0.0 else 0.0
        return Conversion(esc.pulse(tau).value if tau > 0.0 else esc.start_us)


@dataclass(frozen=True, slots=True)
class GimbalRateMap:
    """Pulse (µs) ↔ gimbal rate (rad/s) of a continuous-rotation servo or stepper driver: a dead zone
    ``[lower.x[-1], upper.x[0]]`` of rate 0 between two tables of the same direction."""

    hold_us: float
    lower: MonotoneCubic  # pulses below the dead zone → rate, 0 at its last knot
    upper: MonotoneCubic  # pulses above the dead zone → rate, 0 at its first knot

    def __post_init__(self) -> None:
        hold = finite32(self.hold_us, "hold_us")
        object.__setattr__(self, "hold_us", hold)
        lo, up = self.lower, self.upper
        check_pulse(hold, "hold_us")
        check_pulses(lo.x, "lower.x")
        check_pulses(up.x, "upper.x")
        if lo.y[-1] != 0.0:
            raise CalibrationError(f"the lower table must end at rate 0, not {lo.y[-1]:g}", "lower.y")
        if up.y[0] != 0.0:
            raise CalibrationError(f"the upper table must start at rate 0, not {up.y[0]:g}", "upper.y")
        if lo.rising != up.rising:
            raise CalibrationError("the lower and upper tables turn opposite ways", "upper")
        if not lo.x[-1] <= hold <= up.x[0]:
            raise CalibrationError(
                f"{hold:g} µs is outside the dead zone {lo.x[-1]:g}..{up.x[0]:g} µs", "hold_us"
            )

    @property
    def dead_zone_us(self) -> tuple[float, float]:
        """(first, last) pulse of rate 0."""
        return self.lower.x[-1], self.upper.x[0]

    @property
    def rate_range(self) -> tuple[float, float]:
        """(lowest, highest) rate (rad/s) the driver reaches."""
        return min(self.lower.y[0], self.upper.y[-1]), max(self.lower.y[0], self.upper.y[-1])

    def rate(self, pulse_us: float) -> Conversion:
        """Gimbal rate (rad/s) of ``pulse_us``."""
        p = require_finite(pulse_us, "GimbalRateMap.rate", "pulse_us")
        if p < self.lower.x[-1]:
            return self.lower.evaluate(p)
        if p > self.upper.x[0]:
            return self.upper.evaluate(p)
        return Conversion(0.0)

    def pulse(self, rate_rad_s: float) -> Conversion:
        """The pulse (µs) for ``rate_rad_s``; rate 0 is ``hold_us``."""
        r = require_finite(rate_rad_s, "GimbalRateMap.pulse", "rate_rad_s")
        if r == 0.0:
            return Conversion(self.hold_us)
        side = self.upper if (r > 0.0) == (self.upper.y[-1] > 0.0) else self.lower
        return side.solve(r)


@dataclass(frozen=True, slots=True)
class GimbalAngleMap:
    """Pulse (µs) ↔ gimbal angle (rad) of a positional servo."""

    curve: MonotoneCubic  # pulse µs → angle rad

    def __post_init__(self) -> None:
        check_pulses(self.curve.x, "curve.x")

    def angle(self, pulse_us: float) -> Conversion:
        """Gimbal angle (rad) of ``pulse_us``."""
        return self.curve.evaluate(require_finite(pulse_us, "GimbalAngleMap.angle", "pulse_us"))

    def pulse(self, angle_rad: float) -> Conversion:
        """The pulse (µs) for ``angle_rad``."""
        return self.curve.solve(require_finite(angle_rad, "GimbalAngleMap.pulse", "angle_rad"))

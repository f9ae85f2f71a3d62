"""The stated actuator models: nominal curves of a rotor ESC + BLDC motor and of a gimbal servo.

They define the default calibration (:func:`default_unit_calibration`, the tables sampled from the
nominal models) and the bench data the project generates (``hil.calibration.bench`` adds unit-to-unit
spread and measurement noise to them). ``docs/calibration.md`` states them with their numbers.

Rotor: the ESC's throttle is ``τ = clip((p − low − deadband) / (high − low − deadband), 0, 1)`` and the
steady no-load speed is ``ω = KV·V·f(τ)`` with the concave ``f(τ) = (1 + a)·τ / (1 + a·τ)`` (f(0) = 0,
f(1) = 1): at low throttle the ESC's PWM gains more speed per step than near full throttle.
Defaults: endpoints 1000/2000 µs, 40 µs deadband, KV = 50 rad/s/V (477 rpm/V: 630 rad/s ≈ 6000 rpm on a
full 3S pack, 12.6 V), a = 0.3.

Gimbal: a continuous-rotation servo centred at ``center_us`` with a ±``deadband_us`` dead zone; beyond it
``rate = ±max_rate · g(u)``, ``u`` the distance past the dead zone as a fraction of the rest of the
half-span, ``g(u) = (1 + b)·u / (1 + b·u)``. In ANGLE mode the same channel drives a positional servo:
``angle = range · (s + c·(s³ − s))``, ``s = (p − center) / half_span`` (both negated for a servo mounted
mirrored, ``direction = -1``). Defaults: centre 1500 µs, ±10 µs
dead zone, ±500 µs half-span, ±2 rad/s (the board's gimbal limit), b = 0.6; ±π/2 rad, c = 0.05.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from .cubic import MonotoneCubic
from .maps import EscThrottleMap, GimbalAngleMap, GimbalRateMap, RotorSpeedMap
from .unit import UnitCalibration


@dataclass(frozen=True)
class EscMotorModel:
    """Rotor ESC + BLDC motor (no load). Pulses in µs, KV in rad/s per volt."""

    low_us: float = 1000.0
    high_us: float = 2000.0
    deadband_us: float = 40.0
    kv_rad_s_per_v: float = 50.0
    curvature: float = 0.3

    def throttle(self, pulse_us: float) -> float:
        start = self.low_us + self.deadband_us
        return min(max((pulse_us - start) / (self.high_us - start), 0.0), 1.0)

    def fraction(self, throttle: float) -> float:
        """f(τ): the fraction of the full-throttle speed KV·V at throttle τ."""
        a = self.curvature
        return (1.0 + a) * throttle / (1.0 + a * throttle)

    def speed(self, pulse_us: float, battery_v: float) -> float:
        """Steady no-load speed (rad/s)."""
        return self.kv_rad_s_per_v * battery_v * self.fraction(self.throttle(pulse_us))

    def rotor_map(self, knots: int = 11) -> RotorSpeedMap:
        """The model sampled at ``knots`` evenly spaced throttles."""
        taus = [k / (knots - 1) for k in range(knots)]
        curve = MonotoneCubic.pchip(taus, [self.fraction(t) for t in taus])
        return RotorSpeedMap(
            EscThrottleMap(self.low_us, self.high_us, self.deadband_us), self.kv_rad_s_per_v, curve
        )


@dataclass(frozen=True)
class GimbalServoModel:
    """Gimbal driver: continuous-rotation rate servo (RATE) or positional servo (ANGLE). Pulses in µs."""

    center_us: float = 1500.0
    deadband_us: float = 10.0  # half-width of the dead zone around the centre
    half_span_us: float = 500.0  # centre to either end of the pulse range
    max_rate_rad_s: float = 2.0
    rate_shape: float = 0.6
    angle_range_rad: float = math.pi / 2
    angle_cubic: float = 0.05
    direction: int = 1  # -1: a servo mounted mirrored (more pulse turns the gimbal the negative way)

    def rate(self, pulse_us: float) -> float:
        """Gimbal rate (rad/s); pulses beyond the span are clamped to it."""
        off = min(max(pulse_us - self.center_us, -self.half_span_us), self.half_span_us)
        past = abs(off) - self.deadband_us
        if past <= 0.0:
            return 0.0
        u = past / (self.half_span_us - self.deadband_us)
        b = self.rate_shape
        return math.copysign(self.max_rate_rad_s * (1.0 + b) * u / (1.0 + b * u), off * self.direction)

    def angle(self, pulse_us: float) -> float:
        """Gimbal angle (rad); pulses beyond the span are clamped to it."""
        s = min(max((pulse_us - self.center_us) / self.half_span_us, -1.0), 1.0)
        return self.direction * self.angle_range_rad * (s + self.angle_cubic * (s**3 - s))

    def rate_map(self, knots_per_side: int = 6) -> GimbalRateMap:
        """The rate model sampled at ``knots_per_side`` pulses each side of the dead zone (its edges
        included)."""
        c, d, w = self.center_us, self.deadband_us, self.half_span_us
        upper = [c + d + (w - d) * k / (knots_per_side - 1) for k in range(knots_per_side)]
        lower = [2.0 * c - p for p in reversed(upper)]
        return GimbalRateMap(
            c,
            MonotoneCubic.pchip(lower, [self.rate(p) for p in lower[:-1]] + [0.0]),
            MonotoneCubic.pchip(upper, [0.0] + [self.rate(p) for p in upper[1:]]),
        )

    def angle_map(self, knots: int = 9) -> GimbalAngleMap:
        """The angle model sampled at ``knots`` evenly spaced pulses."""
        c, w = self.center_us, self.half_span_us
        pulses = [c - w + 2.0 * w * k / (knots - 1) for k in range(knots)]
        return GimbalAngleMap(MonotoneCubic.pchip(pulses, [self.angle(p) for p in pulses]))


def model_unit_calibration(motor: EscMotorModel, gimbal: GimbalServoModel) -> UnitCalibration:
    """A unit calibration sampled from actuator models (no fitting, no noise)."""
    return UnitCalibration(motor.rotor_map(), gimbal.rate_map(), gimbal.angle_map())


@functools.cache
def default_unit_calibration() -> UnitCalibration:
    """The nominal unit (:class:`EscMotorModel`, :class:`GimbalServoModel` defaults): 1000–2000 µs ESC
    endpoints, ~630 rad/s at full throttle on 12.6 V, gimbal ±2 rad/s with a 1490–1510 µs hold band,
    ±π/2 rad in ANGLE mode. The same immutable object every call."""
    return model_unit_calibration(EscMotorModel(), GimbalServoModel())

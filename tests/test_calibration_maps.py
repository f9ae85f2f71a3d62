"""Calibration maps: every map against its inverse, monotonicity, saturation, battery dependence, the
PCHIP table against scipy, and validation errors that say where."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.interpolate import PchipInterpolator
from test_calibration_strategies import FINITE, unit_calibrations

from protocol.calibration import (
    Clamp,
    EscThrottleMap,
    GimbalAngleMap,
    GimbalRateMap,
    MonotoneCubic,
    RotorSpeedMap,
    UnitCalibration,
    default_unit_calibration,
    pchip_slopes,
)
from protocol.calibration.checks import f32
from protocol.errors import CalibrationError, FieldRangeError
from protocol.messages import GimbalMode

SETTINGS = settings(max_examples=60, deadline=None)
fractions = st.floats(0.0, 1.0, **FINITE)
volts = st.floats(6.0, 25.0, **FINITE)


def lerp(a: float, b: float, u: float) -> float:
    return a + u * (b - a)


# ------------------------------------------------------------------------- inverse(forward(x)) ≈ x
@SETTINGS
@given(unit_calibrations(), fractions, volts)
def test_rotor_pulse_round_trips_through_speed(cal, u, v):
    esc = cal.rotor.esc
    p = lerp(esc.start_us, esc.high_us, u)
    speed = cal.rotor_speed(p, v)
    assert not speed.saturated
    back = cal.rotor_pulse_us(speed.value, v)
    assert not back.saturated
    if speed.value > 0.0:
        assert back.value == pytest.approx(p, abs=2e-3)
    else:  # the deadband's end: zero speed is the minimum-throttle pulse
        assert back.value == esc.low_us


@SETTINGS
@given(unit_calibrations(), fractions, volts)
def test_rotor_speed_round_trips_through_pulse(cal, u, v):
    top = cal.rotor.full_speed(v)
    w = u * top
    p = cal.rotor_pulse_us(w, v)
    assert not p.saturated
    assert cal.rotor_speed(p.value, v).value == pytest.approx(w, rel=1e-6, abs=1e-6 * top)


@SETTINGS
@given(unit_calibrations(), fractions, st.sampled_from(list(GimbalMode)))
def test_gimbal_value_round_trips_through_pulse(cal, u, mode):
    if mode is GimbalMode.RATE:
        lo, hi = cal.gimbal_rate.rate_range
    else:
        lo, hi = sorted((cal.gimbal_angle.curve.y[0], cal.gimbal_angle.curve.y[-1]))
    x = lerp(lo, hi, u)
    p = cal.gimbal_pulse_us(x, mode)
    assert not p.saturated
    assert cal.gimbal_value(p.value, mode).value == pytest.approx(x, abs=1e-6 * (hi - lo))


@SETTINGS
@given(unit_calibrations(), fractions, st.sampled_from(list(GimbalMode)))
def test_gimbal_pulse_round_trips_through_value(cal, u, mode):
    if mode is GimbalMode.RATE:
        lo_x, hi_x = cal.gimbal_rate.lower.x[0], cal.gimbal_rate.upper.x[-1]
        dz = cal.gimbal_rate.dead_zone_us
    else:
        lo_x, hi_x = cal.gimbal_angle.curve.x_range
        dz = None
    p = lerp(lo_x, hi_x, u)
    value = cal.gimbal_value(p, mode)
    back = cal.gimbal_pulse_us(value.value, mode).value
    if dz is not None and dz[0] <= p <= dz[1]:
        assert value.value == 0.0 and back == cal.gimbal_rate.hold_us
    else:
        assert back == pytest.approx(p, abs=2e-3)


# ------------------------------------------------------------------------- monotone everywhere
@SETTINGS
@given(unit_calibrations(), st.lists(st.floats(400.0, 2600.0, **FINITE), min_size=2, max_size=40), volts)
def test_every_map_is_monotone_in_pulse(cal, pulses, v):
    ps = sorted(pulses)
    speeds = [cal.rotor_speed(p, v).value for p in ps]
    assert all(a <= b for a, b in zip(speeds, speeds[1:], strict=False))
    for mode, curve in ((GimbalMode.RATE, cal.gimbal_rate.upper), (GimbalMode.ANGLE, cal.gimbal_angle.curve)):
        sign = 1.0 if curve.rising else -1.0
        values = [sign * cal.gimbal_value(p, mode).value for p in ps]
        assert all(a <= b for a, b in zip(values, values[1:], strict=False)), mode


@SETTINGS
@given(unit_calibrations(), st.lists(st.floats(-0.1, 1.1, **FINITE), min_size=2, max_size=30), volts)
def test_every_inverse_is_monotone(cal, us, v):
    us = sorted(us)
    top = cal.rotor.full_speed(v)
    pulses = [cal.rotor_pulse_us(u * top, v).value for u in us]
    assert all(a <= b + 1e-6 for a, b in zip(pulses, pulses[1:], strict=False))
    lo, hi = cal.gimbal_rate.rate_range
    sign = 1.0 if cal.gimbal_rate.upper.rising else -1.0
    rates = [sign * cal.gimbal_pulse_us(lerp(lo, hi, u), GimbalMode.RATE).value for u in us]
    assert all(a <= b + 1e-6 for a, b in zip(rates, rates[1:], strict=False))


# ------------------------------------------------------------------------- saturation at the ends
@SETTINGS
@given(unit_calibrations(), volts, st.floats(1e-3, 1e6, **FINITE))
def test_out_of_range_inputs_saturate_and_say_which_end(cal, v, beyond):
    esc = cal.rotor.esc
    assert cal.rotor_speed(esc.low_us - beyond, v).clamp is Clamp.LOW
    assert cal.rotor_speed(esc.low_us - beyond, v).value == 0.0
    high = cal.rotor_speed(esc.high_us + beyond, v)
    assert high.clamp is Clamp.HIGH and high.value == cal.rotor_speed(esc.high_us, v).value
    assert cal.rotor_pulse_us(-beyond, v) == type(high)(esc.low_us, Clamp.LOW)
    top = cal.rotor.full_speed(v)
    assert cal.rotor_pulse_us(top * (1 + 1e-6) + beyond, v) == type(high)(esc.high_us, Clamp.HIGH)
    assert not cal.rotor_pulse_us(0.0, v).saturated and not cal.rotor_pulse_us(top, v).saturated
    for mode, curves in (
        (GimbalMode.RATE, (cal.gimbal_rate.lower, cal.gimbal_rate.upper)),
        (GimbalMode.ANGLE, (cal.gimbal_angle.curve, cal.gimbal_angle.curve)),
    ):
        first, last = curves[0], curves[1]
        lo = cal.gimbal_value(first.x[0] - beyond, mode)
        hi = cal.gimbal_value(last.x[-1] + beyond, mode)
        assert (lo.clamp, lo.value) == (Clamp.LOW, first.y[0])
        assert (hi.clamp, hi.value) == (Clamp.HIGH, last.y[-1])
        y_lo, y_hi = sorted((first.y[0], last.y[-1]))
        below = cal.gimbal_pulse_us(y_lo - beyond, mode)
        above = cal.gimbal_pulse_us(y_hi + beyond, mode)
        assert below.clamp is Clamp.LOW and above.clamp is Clamp.HIGH
        rising = last.rising
        assert below.value == (first.x[0] if rising else last.x[-1])
        assert above.value == (last.x[-1] if rising else first.x[0])


def test_the_board_contract_points():
    cal = default_unit_calibration()
    for v in (9.9, 11.1, 12.6):
        assert cal.rotor_pulse_us(0.0, v).value == cal.rotor.esc.low_us == 1000.0
        hi = cal.rotor_pulse_us(1e9, v)
        assert hi.saturated and hi.value == cal.rotor.esc.high_us == 2000.0
        assert cal.rotor_speed(1000.0, v).value == 0.0
    hold = cal.gimbal_pulse_us(0.0, GimbalMode.RATE)
    assert hold.value == 1500.0 and not hold.saturated
    assert cal.gimbal_pulse_us(15.0, GimbalMode.RATE).saturated  # the board's saturating command
    for rate in (0.4, -0.4, 0.8, -0.8):
        assert not cal.gimbal_pulse_us(rate, GimbalMode.RATE).saturated
    # the DESIGN numbers: ~6000 rpm on a full 3S pack, gimbal up to 2 rad/s
    assert cal.rotor.full_speed(12.6) * 30 / math.pi == pytest.approx(6016, abs=1)
    assert cal.gimbal_rate.rate_range == (-2.0, 2.0)
    assert default_unit_calibration() is cal  # immutable and shared; usable as a cache key
    assert hash(cal) == hash(UnitCalibration.from_bytes(cal.to_bytes()))


# ------------------------------------------------------------------------- battery voltage
@SETTINGS
@given(unit_calibrations(), fractions, st.floats(1.0, 30.0, **FINITE), st.floats(0.01, 10.0, **FINITE))
def test_lower_battery_voltage_means_lower_speed_at_the_same_pulse(cal, u, v, dv):
    esc = cal.rotor.esc
    p = lerp(esc.start_us, esc.high_us, 0.01 + 0.99 * u)
    assert cal.rotor_speed(p, v).value < cal.rotor_speed(p, v + dv).value
    # and so the same speed needs a longer pulse on a sagging pack
    w = 0.5 * cal.rotor.full_speed(v)
    assert cal.rotor_pulse_us(w, v).value > cal.rotor_pulse_us(w, v + dv).value


def test_no_usable_battery_means_no_speed_and_minimum_throttle():
    cal = default_unit_calibration()
    assert cal.rotor_speed(1800.0, 0.5) == type(cal.rotor_speed(0, 0))(0.0, Clamp.LOW)
    out = cal.rotor_pulse_us(300.0, 0.0)
    assert out.value == 1000.0 and out.clamp is Clamp.HIGH  # out of reach; the safe pulse
    assert cal.rotor_pulse_us(0.0, 0.0).value == 1000.0


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda c: c.rotor_pulse_us(math.nan, 12.0), "speed_rad_s"),
        (lambda c: c.rotor_pulse_us(100.0, math.inf), "battery_v"),
        (lambda c: c.rotor_speed(math.nan, 12.0), "pulse_us"),
        (lambda c: c.gimbal_pulse_us(math.nan, GimbalMode.RATE), "rate_rad_s"),
        (lambda c: c.gimbal_pulse_us(-math.inf, GimbalMode.ANGLE), "angle_rad"),
        (lambda c: c.gimbal_value(math.nan, GimbalMode.ANGLE), "pulse_us"),
    ],
)
def test_non_finite_inputs_raise_a_field_range_error(call, field):
    with pytest.raises(FieldRangeError, match=field):
        call(default_unit_calibration())


# ------------------------------------------------------------------------- the table primitive
@st.composite
def monotone_knots(draw):
    n = draw(st.integers(2, 16))
    steps_x = draw(st.lists(st.floats(0.5, 300.0, **FINITE), min_size=n - 1, max_size=n - 1))
    steps_y = draw(st.lists(st.floats(1e-3, 50.0, **FINITE), min_size=n - 1, max_size=n - 1))
    x0 = draw(st.floats(-500.0, 2000.0, **FINITE))
    sign = draw(st.sampled_from([1.0, -1.0]))
    xs = [f32(v) for v in np.concatenate(([x0], x0 + np.cumsum(steps_x)))]
    ys = [f32(v) for v in sign * np.concatenate(([0.0], np.cumsum(steps_y)))]
    assume(all(a < b for a, b in zip(xs, xs[1:], strict=False)))
    assume(all((b - a) * sign > 0 for a, b in zip(ys, ys[1:], strict=False)))
    return xs, ys


@SETTINGS
@given(monotone_knots(), st.floats(0.0, 1.0, **FINITE))
def test_table_is_scipys_pchip(knots, u):
    xs, ys = knots
    ref = PchipInterpolator(xs, ys)
    slopes = pchip_slopes(xs, ys)
    np.testing.assert_allclose(slopes, ref.derivative()(xs), rtol=1e-9, atol=1e-12)
    table = MonotoneCubic.pchip(xs, ys)
    x = lerp(xs[0], xs[-1], u)
    scale = abs(ys[-1] - ys[0])
    assert table.evaluate(x).value == pytest.approx(float(ref(x)), abs=1e-6 * scale)
    assert table.evaluate(table.solve(float(ref(x))).value).value == pytest.approx(
        float(ref(x)), abs=1e-6 * scale
    )


@SETTINGS
@given(monotone_knots())
def test_stored_slopes_stay_in_the_monotone_box_after_float32_rounding(knots):
    xs, ys = knots
    t = MonotoneCubic.pchip(xs, ys)
    for k in range(len(xs) - 1):
        secant = (t.y[k + 1] - t.y[k]) / (t.x[k + 1] - t.x[k])
        for m in (t.slopes[k], t.slopes[k + 1]):
            assert m * secant >= 0.0 and abs(m) <= 3.0 * abs(secant)
    assert MonotoneCubic(t.x, t.y, t.slopes) == t  # the stored numbers are already float32-exact


# ------------------------------------------------------------------------- validation says where
@pytest.mark.parametrize(
    ("build", "where", "phrase"),
    [
        (lambda: MonotoneCubic((0, 1, 1), (0, 1, 2), (1, 1, 1)), "x[2]", "increase strictly"),
        (lambda: MonotoneCubic((0, 1, 2), (0, 2, 1), (0, 0, 0)), "y[2]", "not strictly monotone"),
        (lambda: MonotoneCubic((0, 1, 2), (0, 1, 1), (0, 0, 0)), "y[2]", "not strictly monotone"),
        (lambda: MonotoneCubic((0, 1, 2), (0, 1, 2), (1, 3.5, 1)), "slope[1]", "3x the secant"),
        (lambda: MonotoneCubic((0, 1, 2), (0, 1, 2), (1, -0.1, 1)), "slope[1]", "3x the secant"),
        (lambda: MonotoneCubic((0, 1), (0, math.nan), (1, 1)), "y[1]", "finite"),
        (lambda: MonotoneCubic((0,), (0,), (0,)), "knots", "2 to 16"),
        (lambda: MonotoneCubic(tuple(range(17)), tuple(range(17)), (1,) * 17), "knots", "2 to 16"),
        (lambda: MonotoneCubic((0, 1), (0, 1), (1,)), "knots", "equal counts"),
        (lambda: MonotoneCubic((0, 1), (0, 1e39), (1, 1)), "y[1]", "float32"),
        (lambda: MonotoneCubic((0, 1), (0, "a"), (1, 1)), "y[1]", "not a number"),
        (lambda: EscThrottleMap(2000, 1000, 0), "low_us", "low_us < high_us"),
        (lambda: EscThrottleMap(1000, 2000, 600), "deadband_us", "half the endpoint span"),
        (lambda: EscThrottleMap(100, 2000, 0), "low_us", "500"),
        (
            lambda: RotorSpeedMap(EscThrottleMap(), 0.0, MonotoneCubic.pchip((0, 1), (0, 1))),
            "kv_rad_s_per_v",
            "",
        ),
        (
            lambda: RotorSpeedMap(EscThrottleMap(), 50, MonotoneCubic.pchip((0, 1), (0, 0.9))),
            "curve",
            "(1, 1)",
        ),
        (lambda: RotorSpeedMap(EscThrottleMap(), 50, MonotoneCubic.pchip((0, 1), (1, 0))), "curve", "(0, 0)"),
        (
            lambda: GimbalRateMap(1500, MonotoneCubic.pchip((1000, 1490), (-2, -0.1)), _upper()),
            "lower.y",
            "end at rate 0",
        ),
        (
            lambda: GimbalRateMap(1500, _lower(), MonotoneCubic.pchip((1510, 2000), (0.1, 2))),
            "upper.y",
            "start at",
        ),
        (
            lambda: GimbalRateMap(1500, _lower(), MonotoneCubic.pchip((1510, 2000), (0, -2))),
            "upper",
            "opposite",
        ),
        (lambda: GimbalRateMap(1600, _lower(), _upper()), "hold_us", "outside the dead zone"),
    ],
)
def test_malformed_maps_are_rejected_naming_the_field(build, where, phrase):
    with pytest.raises(CalibrationError) as info:
        build()
    assert info.value.where == where
    assert phrase in str(info.value)


def _lower():
    return MonotoneCubic.pchip((1000, 1490), (-2, 0))


def _upper():
    return MonotoneCubic.pchip((1510, 2000), (0, 2))


def test_gimbal_angle_and_rate_maps_accept_falling_tables():
    rate = GimbalRateMap(
        1500, MonotoneCubic.pchip((1000, 1490), (2, 0)), MonotoneCubic.pchip((1510, 2000), (0, -2))
    )
    assert rate.pulse(1.0).value == pytest.approx(1245.0, abs=1e-6)
    assert rate.pulse(-1.0).value == pytest.approx(1755.0, abs=1e-6)
    angle = GimbalAngleMap(MonotoneCubic.pchip((1000, 2000), (1, -1)))
    assert angle.pulse(0.5).value == pytest.approx(1250.0)

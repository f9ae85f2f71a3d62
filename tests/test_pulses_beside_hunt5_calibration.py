"""Calibration maps beside their tested path: knots, speeds and validation edges one rounding away.

Found by a hunt (area: the shared pulse conversions and calibration tables):

* PCHIP of knots whose secant lies beyond float32's range (two pulses 1e-3 µs apart, angles 1e36 rad
  apart; a table spanning ±3e38) rounded its slope with ``struct`` and raised a bare ``OverflowError``:
  ``hil calibrate show`` of such a file ended in a traceback. Such a slope is now taken at float32's
  largest value, which keeps the cubic monotone, and the firmware accepts the set.
* An integer beyond a float's range (10**400) as a table value or a conversion's argument raised a bare
  ``OverflowError`` (or, past 4300 digits, ``ValueError`` from the error's own message) instead of the
  typed error naming the field.
* A positive rotor speed whose fraction of full speed underflows to 0 (1e-320 rad/s), or whose
  full-throttle speed ``KV·V`` overflows (a battery reading of 1e308 V), was given the ESC's arming pulse
  ``low_us`` — the motor stopped — unflagged. The firmware gives the smallest throttle (the deadband's end).
* The two readers of a binary set split on its validation edges: the deadband rule and the slope box were
  judged in double here and in float32 by the firmware's ``cal_validate``, so a set within a rounding of
  an edge was taken by the emulator (and called valid by ``hil calibrate show``) and refused by the board
  (NACK BAD_CALIBRATION), or the other way round.
"""

from __future__ import annotations

import math
import re
import struct
import subprocess
import sys
from fractions import Fraction

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings
from test_calibration_strategies import unit_calibrations

from firmware_sim.avr.hostlib import cal_validate
from hil.scenario.paths import FIXTURES
from protocol.calibration import (
    EscThrottleMap,
    GimbalAngleMap,
    MonotoneCubic,
    UnitCalibration,
    default_unit_calibration,
)
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError, FieldRangeError
from protocol.messages import PULSE_MAX_US, PULSE_MIN_US, GimbalMode

F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
floats32 = st.floats(-F32_MAX, F32_MAX, width=32)


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def ulps(x: float, n: int) -> float:
    """The float32 ``n`` steps from the positive float32 ``x``."""
    bits = struct.unpack("<I", struct.pack("<f", x))[0] + n
    return struct.unpack("<f", struct.pack("<I", bits))[0]


def with_crc(body: bytes | bytearray) -> bytes:
    body = bytes(body[:-2])
    return body + struct.pack("<H", crc16_ccitt_false(body))


# =========================================================================== PCHIP beyond float32's slopes
@st.composite
def knots(draw, low: float = -F32_MAX, high: float = F32_MAX):
    """2..6 strictly increasing float32 ``x`` in ``low..high`` and strictly monotone float32 ``y``."""
    n = draw(st.integers(2, 6))
    xs = sorted(set(draw(st.lists(st.floats(low, high, width=32), min_size=n, max_size=n))))
    ys = sorted(set(draw(st.lists(floats32, min_size=len(xs), max_size=len(xs)))))
    if draw(st.booleans()):
        ys.reverse()
    return xs, ys


@settings(max_examples=300, deadline=None)
@given(knots())
@example(([0.0, 1.0], [-3e38, 3e38]))
@example(([1000.0, 1000.001, 2000.0], [0.0, 1e36, 2e36]))
def test_pchip_of_any_float32_knots_is_a_table_or_a_calibration_error(table):
    xs, ys = table
    try:
        c = MonotoneCubic.pchip(xs, ys)
    except CalibrationError:
        return  # knots that collide or values not monotone: refused, naming where
    assert all(math.isfinite(m) and abs(m) <= F32_MAX for m in c.slopes)
    assert MonotoneCubic(c.x, c.y, c.slopes) == c  # what the binary set carries reads back


@pytest.mark.firmware
@settings(max_examples=150, deadline=None)
@given(knots(float(PULSE_MIN_US), float(PULSE_MAX_US)))
@example(([1000.0, 1000.001, 2000.0], [0.0, 1e36, 2e36]))
@example(([500.0, 500.0001, 2500.0], [-3e38, 0.0, 3e38]))
def test_an_angle_table_of_any_magnitude_travels_and_the_firmware_takes_it(table):
    try:
        angle = GimbalAngleMap(MonotoneCubic.pchip(*table))
    except CalibrationError:
        return
    d = default_unit_calibration()
    cal = UnitCalibration(d.rotor, d.gimbal_rate, angle)
    assert UnitCalibration.from_bytes(cal.to_bytes()) == cal
    assert cal_validate(cal.to_bytes())[0] == 0


def test_hil_calibrate_show_of_a_file_whose_slope_is_beyond_float32_is_no_traceback(tmp_path):
    """The pyramid fixture with unit 0's angle knots 1e-3 µs apart and 1e36 rad apart."""
    text = (FIXTURES / "calibration" / "pyramid4.toml").read_text()
    text = text.replace("pulse_us = [1000.0, 1125.0,", "pulse_us = [1000.0, 1000.001,", 1)
    angles = ", ".join(f"{k}e36" for k in range(9))
    text = re.sub(r"angle_rad = \[[^\]]*\]", f"angle_rad = [{angles}]", text, count=1)
    path = tmp_path / "steep.toml"
    path.write_text(text)
    done = subprocess.run(
        [sys.executable, "-m", "hil", "calibrate", "show", str(path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 0, done.stderr
    assert "unit 0 (pyramid-0)" in done.stdout


# =========================================================================== integers beyond a float
HUGE_INTS = [10**400, -(10**400), 10**5000]


@pytest.mark.parametrize("value", HUGE_INTS, ids=["1e400", "-1e400", "1e5000"])
@pytest.mark.parametrize(
    "call, field",
    [
        (lambda c, v: c.rotor_pulse_us(v, 12.0), "speed_rad_s"),
        (lambda c, v: c.rotor_pulse_us(100.0, v), "battery_v"),
        (lambda c, v: c.rotor_speed(v, 12.0), "pulse_us"),
        (lambda c, v: c.rotor_speed(1500.0, v), "battery_v"),
        (lambda c, v: c.gimbal_pulse_us(v, GimbalMode.RATE), "rate_rad_s"),
        (lambda c, v: c.gimbal_pulse_us(v, GimbalMode.ANGLE), "angle_rad"),
        (lambda c, v: c.gimbal_value(v, GimbalMode.RATE), "pulse_us"),
        (lambda c, v: c.gimbal_value(v, GimbalMode.ANGLE), "pulse_us"),
    ],
)
def test_a_conversion_of_an_integer_beyond_a_float_is_a_field_range_error(call, field, value):
    with pytest.raises(FieldRangeError) as err:
        call(default_unit_calibration(), value)
    assert err.value.field == field


@pytest.mark.parametrize("value", HUGE_INTS, ids=["1e400", "-1e400", "1e5000"])
@pytest.mark.parametrize(
    "build, where",
    [
        (lambda v: MonotoneCubic.pchip([0.0, v], [0.0, 1.0]), "x[1]"),
        (lambda v: MonotoneCubic((0.0, 1.0), (0.0, v), (1.0, 1.0)), "y[1]"),
        (lambda v: EscThrottleMap(1000.0, v, 0.0), "high_us"),
    ],
)
def test_a_table_value_beyond_a_float_is_a_calibration_error_naming_it(build, where, value):
    with pytest.raises(CalibrationError) as err:
        build(value)
    assert err.value.where == where


# =========================================================================== a positive speed turns the rotor
@settings(max_examples=300, deadline=None)
@given(
    cal=unit_calibrations(),
    speed=st.floats(0.0, 1.7e308, exclude_min=True),
    volts=st.floats(1.0, 1.7e308),
)
@example(cal=default_unit_calibration(), speed=1e-320, volts=12.0)
@example(cal=default_unit_calibration(), speed=1e308, volts=1e308)
def test_a_positive_speed_gets_a_throttle_never_the_arming_pulse(cal, speed, volts):
    """At least the deadband's end, at most full throttle; flagged HIGH exactly when the speed is beyond
    ``KV·V`` (exact arithmetic, a rounding's margin either side)."""
    esc = cal.rotor.esc
    got = cal.rotor_pulse_us(speed, volts)
    assert esc.start_us <= got.value <= esc.high_us, (speed, volts, got)
    full = Fraction(cal.rotor.kv_rad_s_per_v) * Fraction(volts)
    if Fraction(speed) > full * Fraction(1 + 1e-12):
        assert got.clamp.name == "HIGH", (speed, volts, got)
    elif Fraction(speed) < full * Fraction(1 - 1e-12):
        assert not got.saturated, (speed, volts, got)


# =========================================================================== both readers, one verdict
def _readers_agree(blob: bytes) -> None:
    try:
        UnitCalibration.from_bytes(blob)
        python_ok = True
    except CalibrationError:
        python_ok = False
    status = cal_validate(blob)[0]
    assert (status == 0) == python_ok, (
        f"Python {'takes' if python_ok else 'refuses'}, the firmware says {status}"
    )


@pytest.mark.firmware
@settings(max_examples=300, deadline=None)
@given(
    low=st.floats(500.0, 2400.0, width=32),
    span=st.floats(1e-3, 2000.0),
    step=st.integers(-2, 2),
)
@example(low=825.4743041992188, span=2151.149169921875 - 825.4743041992188, step=-1)
def test_a_deadband_at_half_the_span_is_judged_by_both_readers_alike(low, span, step):
    high = f32(min(low + span, 2500.0))
    if not low < high:
        return
    dead = ulps(f32(0.5 * (high - low)), step)
    blob = bytearray(default_unit_calibration().to_bytes())
    struct.pack_into("<fff", blob, 4, low, high, dead)
    _readers_agree(with_crc(blob))


@pytest.mark.firmware
@settings(max_examples=300, deadline=None)
@given(
    x0=st.floats(500.0, 2400.0, width=32),
    dx=st.floats(1e-3, 2000.0),
    y0=st.floats(-3.0, 3.0, width=32),
    dy=st.floats(1e-6, 6.0),
    falling=st.booleans(),
    knot=st.integers(0, 1),
    step=st.integers(-3, 3),
)
@example(x0=500.0, dx=1.0, y0=0.0, dy=1.25, falling=False, knot=0, step=1)  # the firmware took it
def test_a_slope_at_the_edge_of_its_box_is_judged_by_both_readers_alike(x0, dx, y0, dy, falling, knot, step):
    """A two-knot angle table whose knot ``knot`` has a slope ``step`` float32 steps from the readers'
    edge, 3·(1 + 1e-5) times the secant."""
    x1, y1 = f32(min(x0 + dx, 2500.0)), f32(y0 + dy)
    if not (x0 < x1 and y0 < y1):
        return
    ys = (y1, y0) if falling else (y0, y1)
    d = default_unit_calibration()
    cal = UnitCalibration(d.rotor, d.gimbal_rate, GimbalAngleMap(MonotoneCubic((x0, x1), ys, (0.0, 0.0))))
    edge = f32(3.0 * (y1 - y0) / (x1 - x0) * (1.0 + 1e-5))
    slope = ulps(edge, step) * (-1.0 if falling else 1.0)
    blob = bytearray(cal.to_bytes())
    struct.pack_into("<f", blob, len(blob) - 2 - 24 + 12 * knot + 8, slope)
    _readers_agree(with_crc(blob))

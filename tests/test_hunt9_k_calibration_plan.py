"""The calibration tables' conversions through their precomputed constants (``MonotoneCubic._plan``, issue
29: the board emulator's pulse frame) give the reference's bits for every input.

``MonotoneCubic.evaluate`` / ``solve`` read each interval's constants computed once with the table;
``evaluate_reference`` / ``solve_reference`` are the per-call algorithm ``docs/calibration.md`` §2
specifies (what a C port follows line by line), kept as the oracle. Every value is compared by its bytes
(so -0.0 against 0.0 and NaN's payload count) and every clamp flag by identity of meaning."""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle
import struct

from hypothesis import assume, given, settings
from hypothesis import strategies as st
from test_calibration_strategies import unit_calibrations

from protocol.calibration import MonotoneCubic, UnitCalibration, default_unit_calibration
from protocol.errors import CalibrationError
from protocol.messages import GimbalMode

FINITE = {"allow_nan": False, "allow_infinity": False}


def _bits(conversion) -> tuple[bytes, int]:
    return struct.pack("<d", conversion.value), int(conversion.clamp)


def _probes(table: MonotoneCubic, axis: tuple[float, ...], drawn: list[float]) -> list[float]:
    """Inputs beside the tested path: each knot exactly and one ulp either side, the table's ends and
    beyond, ±0, ±inf, NaN, the largest floats, and the drawn values."""
    out = [0.0, -0.0, math.inf, -math.inf, math.nan, 1e308, -1e308, 5e-324, -5e-324, *drawn]
    for v in axis:
        out += [v, math.nextafter(v, math.inf), math.nextafter(v, -math.inf)]
    return out


def _assert_same(table: MonotoneCubic, xs: list[float], ys: list[float]) -> None:
    for x in _probes(table, table.x, xs):
        assert _bits(table.evaluate(x)) == _bits(table.evaluate_reference(x)), ("evaluate", table, x)
    for y in _probes(table, table.y, ys):
        assert _bits(table.solve(y)) == _bits(table.solve_reference(y)), ("solve", table, y)


@st.composite
def tables(draw) -> MonotoneCubic:
    """A PCHIP table of 2..16 knots, rising or falling, at scales from subnormal to float32's largest."""
    n = draw(st.integers(2, 16))
    scale_x = draw(st.sampled_from([1e-30, 1e-3, 1.0, 1e3, 1e30]))
    scale_y = draw(st.sampled_from([1e-40, 1e-20, 1e-3, 1.0, 1e3, 1e20, 1e36]))
    start = draw(st.floats(-1e3, 1e3, **FINITE))
    steps_x = draw(st.lists(st.floats(0.01, 10.0, **FINITE), min_size=n - 1, max_size=n - 1))
    steps_y = draw(st.lists(st.floats(0.01, 10.0, **FINITE), min_size=n - 1, max_size=n - 1))
    sign = draw(st.sampled_from([1.0, -1.0]))
    x = [start * scale_x]
    y = [draw(st.floats(-10.0, 10.0, **FINITE)) * scale_y]
    for dx, dy in zip(steps_x, steps_y, strict=True):
        x.append(x[-1] + dx * scale_x)
        y.append(y[-1] + sign * dy * scale_y)
    try:
        return MonotoneCubic.pchip(x, y)
    except CalibrationError:  # knots that float32 rounds together: no table
        assume(False)
        raise


inputs = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=400, deadline=None)
@given(tables(), st.lists(inputs, max_size=12), st.lists(inputs, max_size=12), st.data())
def test_a_tables_conversions_are_the_references_bit_for_bit(table, xs, ys, data):
    lo, hi = table.x_range
    ylo, yhi = table.y_range
    xs += data.draw(st.lists(st.floats(lo, hi), max_size=12))
    ys += data.draw(st.lists(st.floats(ylo, yhi), max_size=12))
    _assert_same(table, xs, ys)


@settings(max_examples=150, deadline=None)
@given(
    unit_calibrations(),
    st.lists(st.floats(-5.0, 5.0), max_size=10),
    st.lists(st.floats(400.0, 2600.0), max_size=10),
)
def test_every_table_of_a_unit_converts_as_its_reference(cal: UnitCalibration, values, pulses):
    for table in (cal.rotor.curve, cal.gimbal_rate.lower, cal.gimbal_rate.upper, cal.gimbal_angle.curve):
        _assert_same(table, pulses + values, values + [0.5])


def test_the_default_units_gimbal_frame_converts_as_the_reference():
    """The run's own table: every rate a pulse frame asks for in 1e-4 rad/s steps over ±2.2 rad/s, and
    every pulse in 0.01 µs steps over 900..2100 µs."""
    cal = default_unit_calibration()
    rate = cal.gimbal_rate
    for k in range(-22000, 22001):
        r = k * 1e-4
        side = rate.upper if (r > 0.0) == (rate.upper.y[-1] > 0.0) else rate.lower
        assert _bits(side.solve(r)) == _bits(side.solve_reference(r)), r
    for table in (rate.lower, rate.upper, cal.gimbal_angle.curve):
        for k in range(90000, 210001, 7):
            p = k * 0.01
            assert _bits(table.evaluate(p)) == _bits(table.evaluate_reference(p)), p
    assert cal.gimbal_pulse_us(0.0, GimbalMode.RATE).value == rate.hold_us


@given(tables())
def test_a_copied_replaced_or_unpickled_table_converts_as_its_own_reference(table):
    """The constants are the table's: equality, hash and repr ignore them, and every way of making a table
    again (a copy, a pickle, ``dataclasses.replace`` with new values) carries or recomputes them."""
    flipped = dataclasses.replace(table, y=tuple(-v for v in table.y), slopes=tuple(-m for m in table.slopes))
    for other in (copy.copy(table), copy.deepcopy(table), pickle.loads(pickle.dumps(table)), flipped):
        mid = 0.5 * (other.y[0] + other.y[-1])
        _assert_same(other, [0.5 * (other.x[0] + other.x[-1])], [mid])
    assert copy.copy(table) == table and hash(copy.copy(table)) == hash(table)
    assert "_plan" not in repr(table)
    assert flipped.solve(-table.y[0]).value == flipped.solve_reference(-table.y[0]).value

"""Calibration sets that are valid but reach the ends of float32's range, in the C firmware as in Python.

A gimbal angle (or rate) table whose values run from -3e38 to 3e38 is absurd but well-formed: both
validations accept it (every number finite, the tables monotone, the slopes inside their box). Python
evaluates it in double; the firmware evaluated it in float32, where ``y1 - y0`` and ``3 * d`` overflow to
infinity and the cubic to NaN: a gimbal commanded to angle 0 went out at 2000 µs (full deflection) where
the emulator put out 1500 µs, and every angle the board read back from its pulses was NaN. The firmware's
validation, comparing slopes with an infinite secant, also accepted slopes the reference refuses. At the
other end, a table of subnormal values (±1e-43 rad) lost its bits in float32: widths 4.5 µs off.

Checked on the firmware's own C (``calib.c`` through its host library) against ``protocol.calibration``
for drawn magnitudes, and end to end: the set uploaded to the firmware on simavr and to the Python board,
an ANGLE setpoint, and the width each board reports.
"""

from __future__ import annotations

import math
import struct

import hypothesis.strategies as st
import pytest
from conformance.host import LockstepHost, SerialHost, heartbeat
from hypothesis import assume, example, given, settings

from firmware_sim.avr import AvrBoard
from firmware_sim.avr.hostlib import cal_call, cal_validate
from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock
from protocol.calibration import MonotoneCubic, UnitCalibration, default_unit_calibration, fragment
from protocol.calibration.maps import GimbalAngleMap, GimbalRateMap
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError
from protocol.messages import Ack, ActuatorSetpoint, Arm, BoardState, GimbalMode, Telemetry, UnitSetpoint

ANGLE, RATE = int(GimbalMode.ANGLE), int(GimbalMode.RATE)
F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
PULSE_TOL_US = 0.01  # float32 against double (tests/test_firmware_calibration.py)


def f32(x: float) -> float:
    """``x`` as the wire carries it (float32; beyond its range, its largest value)."""
    return struct.unpack("<f", struct.pack("<f", max(-F32_MAX, min(F32_MAX, x))))[0]


def _table(x0: float, x1: float, y0: float, y1: float, knots: int) -> MonotoneCubic:
    """A PCHIP table of ``knots`` knots evenly from (x0, y0) to (x1, y1) (float32)."""
    xs = [x0 + (x1 - x0) * k / (knots - 1) for k in range(knots)]
    ys = [f32(y0 + (y1 - y0) * k / (knots - 1)) for k in range(knots)]
    return MonotoneCubic.pchip(xs, ys)


def huge(angle_top: float, rate_top: float, knots: int = 2) -> UnitCalibration:
    """The default unit with gimbal tables of ``knots`` knots spanning ±``angle_top`` rad and
    ±``rate_top`` rad/s (few knots: each interval spans a large part of float32's range)."""
    cal = default_unit_calibration()
    return UnitCalibration(
        cal.rotor,
        GimbalRateMap(
            1500.0,
            _table(1000.0, 1490.0, -rate_top, 0.0, knots),
            _table(1510.0, 2000.0, 0.0, rate_top, knots),
        ),
        GimbalAngleMap(_table(1000.0, 2000.0, -angle_top, angle_top, knots)),
    )


factors = st.one_of(
    st.sampled_from([1.0, 2.0**63, 2.0**64, 1e19, 1e30, 1e37, 1.2e38, 1.8e38, 3e38, F32_MAX]),
    st.sampled_from([2.0**-64, 2.0**-65, 1e-30, 1e-38, 1e-40, 1e-43]),  # subnormal tables
    st.floats(f32(1e-43), F32_MAX, width=32),
)


def buildable(angle_top: float, rate_top: float, knots: int) -> UnitCalibration:
    """:func:`huge`, or the example dropped where Python itself refuses the tables (knots of a subnormal
    table that round onto each other)."""
    try:
        return huge(angle_top, rate_top, knots)
    except CalibrationError:
        assume(False)
        raise


@pytest.mark.firmware
@settings(max_examples=80, deadline=None)
@given(angle_factor=factors, rate_factor=factors, knots=st.sampled_from([2, 3, 5]), data=st.data())
def test_a_huge_but_valid_table_converts_in_c_as_in_python(angle_factor, rate_factor, knots, data):
    cal = buildable(angle_factor, rate_factor, knots)
    blob = cal.to_bytes()
    assert cal_validate(blob)[0] == 0
    fractions = st.floats(-1.2, 1.2)
    for frac in data.draw(st.lists(fractions, min_size=1, max_size=5), label="angles") + [0.0]:
        a = f32(frac * angle_factor)  # what the wire carries
        value, clamp = cal_call("gimbal_pulse_us", blob, a, ANGLE)
        want = cal.gimbal_pulse_us(a, GimbalMode.ANGLE)
        assert clamp == int(want.clamp) and abs(value - want.value) <= PULSE_TOL_US, (a, value, want)
    for frac in data.draw(st.lists(fractions, min_size=1, max_size=5), label="rates") + [0.0]:
        r = f32(frac * rate_factor)
        value, clamp = cal_call("gimbal_pulse_us", blob, r, RATE)
        want = cal.gimbal_pulse_us(r, GimbalMode.RATE)
        assert clamp == int(want.clamp) and abs(value - want.value) <= PULSE_TOL_US, (r, value, want)
    pulses = data.draw(st.lists(st.floats(900.0, 2100.0, width=32), min_size=1, max_size=5), label="pulses")
    for p in pulses + [1500.0]:
        for mode, factor in ((GimbalMode.ANGLE, angle_factor), (GimbalMode.RATE, rate_factor)):
            value, clamp = cal_call("gimbal_value", blob, p, int(mode))
            want = cal.gimbal_value(p, mode)
            assert math.isfinite(value), (p, mode, value)
            tol = 1e-5 * factor + 2.0**-149  # the C's value is a float32: a subnormal has its step
            assert clamp == int(want.clamp) and abs(value - want.value) <= tol, (p, mode, value, want)


def _with_slope(blob: bytes, table: int, knot: int, slope: float) -> bytes:
    body = bytearray(blob[:-2])
    offset = 28 + 12 * (sum(blob[24 : 24 + table]) + knot) + 8
    struct.pack_into("<f", body, offset, slope)
    return bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body)))


@pytest.mark.firmware
@settings(max_examples=80, deadline=None)
@given(
    factor=factors,
    knots=st.sampled_from([2, 3, 5]),
    knot=st.integers(0, 4),
    slope_factor=st.one_of(st.floats(-5.0, 5.0), st.sampled_from([2.9, 3.0, 3.1, 10.0, -0.5])),
)
@example(factor=3e38, knots=2, knot=0, slope_factor=10.0)  # y1 - y0 overflows: any slope passed in C
@example(factor=3e38, knots=2, knot=1, slope_factor=-0.5)
def test_a_slope_in_a_huge_table_is_judged_in_c_as_in_python(factor, knots, knot, slope_factor):
    """The angle table's knot ``knot`` gets a slope ``slope_factor`` times its neighbouring secant: the
    firmware refuses exactly what Python refuses."""
    cal = buildable(factor, 1.0, knots)
    curve = cal.gimbal_angle.curve
    knot = min(knot, knots - 1)
    k = min(knot, knots - 2)
    secant = (curve.y[k + 1] - curve.y[k]) / (curve.x[k + 1] - curve.x[k])
    slope = f32(slope_factor * secant)
    blob = _with_slope(cal.to_bytes(), 3, knot, slope)
    try:
        UnitCalibration.from_bytes(blob)
        python_ok = True
    except CalibrationError:
        python_ok = False
    assert (cal_validate(blob)[0] == 0) == python_ok, (factor, knot, slope)


# --------------------------------------------------------------------------- end to end, both boards
CONFIG = BoardConfig(telemetry_rate_hz=50.0, link_timeout_s=10.0)
HUGE = huge(3e38, 3e38)
SETPOINTS = [0.0, 99.0, -99.0]  # angles (rad): as far as the wire carries (±100), all mid-table


def _angles(host) -> list[tuple[float, int, int]]:
    """Per setpoint: the angle, the width the board reports on unit 0's gimbal, the one Python computes."""
    assert all(isinstance(a, Ack) for a in (host.request(m) for m in fragment(0, 1, HUGE.to_bytes())))
    assert isinstance(host.request(Arm()), Ack)
    seen = []
    for angle in SETPOINTS:
        sp = ActuatorSetpoint(
            gimbal_mode=GimbalMode.ANGLE, units=tuple(UnitSetpoint(angle, 0.0) for _ in range(4))
        )
        host.keepalive = lambda sp=sp: sp
        host.poll(0.3)
        tel = host.wait_type(Telemetry, 1.0, lambda m: m.state == BoardState.ARMED)
        seen.append((angle, tel.pulses_us[0], round(HUGE.gimbal_pulse_us(angle, GimbalMode.ANGLE).value)))
    host.keepalive = heartbeat
    return seen


@pytest.mark.firmware
def test_the_firmware_on_simavr_drives_a_huge_angle_table_as_the_reference():
    with AvrBoard(CONFIG) as board:
        host = SerialHost(board.port)
        try:
            host.handshake()
            host.keepalive = heartbeat
            seen = _angles(host)
        finally:
            host.close()
        board.check()
    for angle, width, want in seen:
        assert abs(width - want) <= 1, f"angle {angle:g} rad: the firmware put out {width} µs, want {want}"


def test_the_python_board_drives_a_huge_angle_table_as_the_reference():
    clock = LockstepClock()
    board = Board(CONFIG, clock)
    host = LockstepHost(board, clock)
    host.poll(board.config.boot_time_s + 0.001)
    host.handshake()
    host.keepalive = heartbeat
    for angle, width, want in _angles(host):
        assert abs(width - want) <= 1, f"angle {angle:g} rad: the emulator put out {width} µs, want {want}"

"""The firmware's calibration maps (firmware/src/calib.c) against protocol.calibration, on the same sets.

The C port runs in float32 (as on the ATmega); the Python reference in double. Values must agree to well
under the pulse hardware's resolution (0.5 µs) and the clamp flags exactly; the C validation must accept
every set Python accepts and refuse the malformed ones Python refuses.
"""

from __future__ import annotations

import json
import math
import struct

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_calibration_strategies import unit_calibrations

from firmware_sim.avr.hostlib import cal_call, cal_status_text, cal_validate
from hil.scenario.paths import FIXTURES
from protocol.calibration import (
    EscThrottleMap,
    MonotoneCubic,
    RotorSpeedMap,
    UnitCalibration,
    default_unit_calibration,
)
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError
from protocol.messages import GimbalMode

PULSE_TOL_US = 0.01  # float32 against double, far below the 0.5 µs timer tick
RATE, ANGLE = int(GimbalMode.RATE), int(GimbalMode.ANGLE)


def _close(c: tuple[float, int], py, tol: float, what: str) -> None:
    value, clamp = c
    assert clamp == int(py.clamp), f"{what}: clamp {clamp} != {py.clamp!r}"
    assert math.isclose(value, py.value, rel_tol=2e-6, abs_tol=tol), f"{what}: {value} != {py.value}"


def check_maps(cal: UnitCalibration, speeds, volts, rates, angles, pulses) -> None:
    data = cal.to_bytes()
    for v in volts:
        for w in speeds:
            _close(
                cal_call("rotor_pulse_us", data, w, v),
                cal.rotor_pulse_us(w, v),
                PULSE_TOL_US,
                f"rotor {w} @ {v}",
            )
        for p in pulses:
            scale = max(1.0, cal.rotor.full_speed(v))
            _close(
                cal_call("rotor_speed", data, p, v), cal.rotor_speed(p, v), 1e-5 * scale, f"speed {p} @ {v}"
            )
    for r in rates:
        _close(
            cal_call("gimbal_pulse_us", data, r, RATE),
            cal.gimbal_pulse_us(r, GimbalMode.RATE),
            PULSE_TOL_US,
            f"rate {r}",
        )
    for a in angles:
        _close(
            cal_call("gimbal_pulse_us", data, a, ANGLE),
            cal.gimbal_pulse_us(a, GimbalMode.ANGLE),
            PULSE_TOL_US,
            f"angle {a}",
        )
    for p in pulses:
        for mode, m in ((RATE, GimbalMode.RATE), (ANGLE, GimbalMode.ANGLE)):
            _close(
                cal_call("gimbal_value", data, p, mode), cal.gimbal_value(p, m), 1e-5, f"value {p} mode {m}"
            )


CAL_VECTORS = json.loads((FIXTURES / "calibration" / "vectors.json").read_text())
CLAMPS = {"NONE": 0, "LOW": 1, "HIGH": 2}


@pytest.mark.firmware
@pytest.mark.parametrize("vector_set", CAL_VECTORS["sets"], ids=lambda v: v["name"])
def test_the_calibration_vectors_pass_in_c(vector_set):
    """docs/calibration.md §6: every clamp matches, every value within the stated tolerance."""
    tol = CAL_VECTORS["tolerance"]
    data = bytes.fromhex(vector_set["hex"])
    assert len(data) == vector_set["size"] and cal_validate(data)[0] == 0
    for case in vector_set["cases"]:
        value, clamp = cal_call(case["fn"], data, *case["in"])
        assert clamp == CLAMPS[case["clamp"]], case
        want = case["out"]
        if case["fn"] == "rotor_speed":
            assert math.isclose(value, want, rel_tol=tol["rotor_speed_relative"], abs_tol=1e-9), case
        elif case["fn"] == "gimbal_value":
            assert abs(value - want) <= tol["gimbal_rate_rad_s"], case
        else:
            assert abs(value - want) <= tol["pulse_us"], case


@pytest.mark.firmware
@pytest.mark.parametrize("bad", CAL_VECTORS["malformed"], ids=lambda v: v["what"])
def test_the_malformed_calibration_vectors_are_refused_in_c(bad):
    assert cal_validate(bytes.fromhex(bad["hex"]))[0] != 0


@pytest.mark.firmware
def test_default_set_is_valid_and_converts_like_python():
    cal = default_unit_calibration()
    assert cal_validate(cal.to_bytes()) == (0, 0xFF, 0)
    check_maps(
        cal,
        speeds=[-5.0, 0.0, 1e-3, 50.0, 300.0, 450.0, 629.0, 630.0, 700.0, 1e9],
        volts=[0.5, 1.0, 9.0, 11.1, 12.6],
        rates=[-3.0, -2.0, -0.7, -1e-3, 0.0, 1e-3, 0.3, 1.99, 2.0, 5.0],
        angles=[-2.0, -1.5, -0.3, 0.0, 0.4, 1.5707, 3.0],
        pulses=[500.0, 999.0, 1000.0, 1040.0, 1300.5, 1490.0, 1500.0, 1511.0, 1999.0, 2000.0, 2500.0],
    )


@pytest.mark.firmware
@settings(max_examples=60, deadline=None)
@given(cal=unit_calibrations(), data=st.data())
def test_random_units_convert_like_python(cal, data):
    assert cal_validate(cal.to_bytes())[0] == 0
    floats = st.floats(allow_nan=False, allow_infinity=False, width=32)
    check_maps(
        cal,
        speeds=data.draw(st.lists(floats.filter(lambda x: -100 <= x <= 3000), min_size=1, max_size=6)),
        volts=data.draw(st.lists(st.floats(0.0, 30.0, width=32), min_size=1, max_size=3)),
        rates=data.draw(st.lists(st.floats(-12.0, 12.0, width=32), min_size=1, max_size=6)),
        angles=data.draw(st.lists(st.floats(-4.0, 4.0, width=32), min_size=1, max_size=6)),
        pulses=data.draw(st.lists(st.floats(400.0, 2600.0, width=32), min_size=1, max_size=6)),
    )


# --------------------------------------------------------------------------- refusing malformed sets
def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<H", crc16_ccitt_false(body))


def _knot_offset(data: bytes, table: int, knot: int) -> int:
    return 28 + 12 * (sum(data[24 : 24 + table]) + knot)


def _set_f32(data: bytes, offset: int, value: float) -> bytes:
    body = bytearray(data[:-2])
    struct.pack_into("<f", body, offset, value)
    return _with_crc(bytes(body))


def _mutations(data: bytes) -> dict[str, bytes]:
    body = data[:-2]
    swap = bytearray(body)
    a, b = _knot_offset(data, 0, 1), _knot_offset(data, 0, 2)
    swap[a : a + 12], swap[b : b + 12] = body[b : b + 12], body[a : a + 12]
    slope_at = _knot_offset(data, 3, 1) + 8
    (slope,) = struct.unpack_from("<f", data, slope_at)
    return {
        "truncated": data[:20],
        "magic": _with_crc(b"XC" + body[2:]),
        "version": _with_crc(body[:2] + b"\x02" + body[3:]),
        "flags": _with_crc(body[:3] + b"\x01" + body[4:]),
        "count": _with_crc(body[:24] + b"\x01" + body[25:]),
        "length": data + b"\x00",
        "crc": data[:-1] + bytes([data[-1] ^ 0xFF]),
        "nan knot": _set_f32(data, _knot_offset(data, 1, 0) + 4, float("nan")),
        "x order": _with_crc(bytes(swap)),
        "steep slope": _set_f32(data, slope_at, slope * 50.0),
        "esc endpoints": _set_f32(data, 4, 2400.0),
        "kv": _set_f32(data, 16, -1.0),
        "curve end": _set_f32(data, _knot_offset(data, 0, data[24] - 1) + 4, 0.9),
        "dead zone": _set_f32(data, _knot_offset(data, 2, 0) + 4, 0.05),
        "hold": _set_f32(data, 20, 900.0),
    }


@pytest.mark.firmware
@pytest.mark.parametrize("kind", list(_mutations(default_unit_calibration().to_bytes())))
def test_malformed_sets_are_refused_like_python(kind):
    bad = _mutations(default_unit_calibration().to_bytes())[kind]
    with pytest.raises(CalibrationError):
        UnitCalibration.from_bytes(bad)
    status, _, _ = cal_validate(bad)
    assert status != 0, f"{kind}: the firmware accepted a set Python refuses"
    assert cal_status_text(status) not in ("ok", "unknown")


@pytest.mark.firmware
@pytest.mark.parametrize("tiny", [2.788583944006386e-42, 1e-40, 1e-39, 1e-36])
@pytest.mark.parametrize("default", [True, False], ids=["default unit", "low 900 deadband 1 kv 190"])
def test_a_subnormal_rotor_speed_is_still_the_smallest_throttle_in_c_as_in_python(tiny, default):
    """Hypothesis found it: a speed whose throttle fraction is subnormal in float32 was solved to throttle
    0 by the C (the arming pulse, 900 µs) and to a throttle just above it by Python (901 µs: the deadband's
    end). A positive speed is the smallest throttle on both."""
    cal = default_unit_calibration()
    if not default:
        esc = EscThrottleMap(low_us=900.0, high_us=1800.0, deadband_us=1.0)
        rotor = RotorSpeedMap(esc, 190.0, MonotoneCubic.pchip((0.0, 0.5, 1.0), (0.0, 2 / 3, 1.0)))
        cal = UnitCalibration(rotor, cal.gimbal_rate, cal.gimbal_angle)
    check_maps(cal, speeds=[tiny, -tiny], volts=[7.0], rates=[tiny, -tiny], angles=[tiny], pulses=[1500.0])
    assert cal.rotor_pulse_us(tiny, 7.0).value == cal.rotor.esc.start_us

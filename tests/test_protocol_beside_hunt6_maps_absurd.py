"""The calibration maps and the message fields, with values that parse but are absurd.

A hunt beside the tested paths (voltages of 6–25 V, numbers that are floats) found:

* ``RotorSpeedMap.speed`` at a battery reading of 1e308 V gave ``Conversion(inf)`` unflagged at any
  throttle above 0 and NaN at throttle 0 (``KV·V`` overflowed, and inf · 0 is NaN); ``full_speed`` gave inf
  there and took NaN for "no supply" (0 rad/s);
* every map took a string (``"1500"`` as a pulse of 1500 µs), a bool (``True`` as a gimbal rate of 1 rad/s)
  or bytes as a number, and raised a bare ``TypeError`` for None; a map's table took ``"1000"`` as a knot;
* building :class:`FieldRangeError` for an integer past 4300 digits (a message field, a map's input, a
  pulse width of ``10**5000``) raised Python's own ``ValueError`` ("Exceeds the limit (4300 digits)")
  instead of the typed error;
* a float field refused numpy's float32 1.0 (what a float32 controller computes) as "out of range",
  where :func:`protocol.numbers.real_number` says a message's float fields take numpy's scalars.

The C extension (``protocol/_speedups.c``) does COBS and CRC only: field values are judged in Python on
both paths; the last test checks the two paths judge the same values alike, through real subprocesses.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import example, given, settings

from protocol.calibration import EscThrottleMap, MonotoneCubic, default_unit_calibration
from protocol.errors import CalibrationError, FieldRangeError, value_repr
from protocol.frame import decode_frame, encode_frame
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint

ROOT = Path(__file__).resolve().parent.parent
CAL = default_unit_calibration()
any_volts = st.floats(allow_nan=True, allow_infinity=True)
pulses = st.floats(0.0, 3000.0)


@settings(max_examples=300, deadline=None)
@given(pulse=pulses, volts=any_volts)
@example(pulse=1000.0, volts=1e308)  # throttle 0: was NaN
@example(pulse=1500.0, volts=1e308)  # was inf, unflagged
@example(pulse=1500.0, volts=1.7e308)
@example(pulse=1500.0, volts=-0.0)
def test_a_rotor_speed_at_any_voltage_is_a_finite_speed_or_an_error_naming_the_voltage(pulse, volts):
    """A speed is a finite number of rad/s, 0 when the rotor is off (throttle 0) or there is no supply —
    or a :class:`FieldRangeError` naming ``battery_v``; never inf or NaN."""
    try:
        got = CAL.rotor_speed(pulse, volts)
    except FieldRangeError as exc:
        assert exc.field == "battery_v" and exc.message_name == "RotorSpeedMap.speed", exc
        assert not math.isfinite(volts) or math.isinf(CAL.rotor.kv_rad_s_per_v * volts), volts
        return
    assert math.isfinite(got.value) and got.value >= 0.0, (pulse, volts, got)
    if pulse <= CAL.rotor.esc.start_us or volts < 1.0:
        assert got.value == 0.0, (pulse, volts, got)


@settings(max_examples=200, deadline=None)
@given(volts=any_volts)
@example(volts=math.nan)  # was 0 rad/s: NaN taken for "no supply"
@example(volts=1e308)  # was inf
def test_full_speed_is_finite_or_an_error_naming_the_voltage(volts):
    try:
        top = CAL.rotor.full_speed(volts)
    except FieldRangeError as exc:
        assert exc.field == "battery_v", exc
        assert not math.isfinite(volts) or math.isinf(CAL.rotor.kv_rad_s_per_v * volts), volts
        return
    assert math.isfinite(top) and top >= 0.0, (volts, top)


CONVERSIONS = [
    ("rotor_speed", lambda x: CAL.rotor_speed(x, 12.0), "EscThrottleMap.throttle", "pulse_us"),
    ("rotor_speed battery", lambda x: CAL.rotor_speed(1500.0, x), "RotorSpeedMap.speed", "battery_v"),
    ("rotor_pulse_us", lambda x: CAL.rotor_pulse_us(x, 12.0), "RotorSpeedMap.pulse", "speed_rad_s"),
    ("rotor_pulse_us battery", lambda x: CAL.rotor_pulse_us(100.0, x), "RotorSpeedMap.pulse", "battery_v"),
    ("gimbal_pulse_us rate", lambda x: CAL.gimbal_pulse_us(x, GimbalMode.RATE), "GimbalRateMap.pulse", None),
    (
        "gimbal_pulse_us angle",
        lambda x: CAL.gimbal_pulse_us(x, GimbalMode.ANGLE),
        "GimbalAngleMap.pulse",
        None,
    ),
    ("gimbal_value rate", lambda x: CAL.gimbal_value(x, GimbalMode.RATE), "GimbalRateMap.rate", None),
    ("gimbal_value angle", lambda x: CAL.gimbal_value(x, GimbalMode.ANGLE), "GimbalAngleMap.angle", None),
    ("full_speed", CAL.rotor.full_speed, "RotorSpeedMap.full_speed", "battery_v"),
]
NO_NUMBERS = ["1500", True, False, b"1", None, [1500.0], np.bool_(True), 10**5000, -(10**5000), math.nan]


@pytest.mark.parametrize("bad", NO_NUMBERS, ids=lambda v: type(v).__name__)
@pytest.mark.parametrize(("name", "call", "what", "field"), CONVERSIONS, ids=[c[0] for c in CONVERSIONS])
def test_a_map_refuses_what_is_no_finite_number_naming_the_argument(name, call, what, field, bad):
    """A string, a bool, bytes, None, a list, an integer past a float, NaN: a typed error naming the map
    and the argument (and whose message can be built), never a number made of it or a bare TypeError."""
    with pytest.raises(FieldRangeError) as caught:
        call(bad)
    assert caught.value.message_name == what, caught.value
    if field is not None:
        assert caught.value.field == field, caught.value
    assert len(str(caught.value)) < 200


@pytest.mark.parametrize("wrap", [np.float32, np.float64, np.int64, np.array], ids=lambda w: w.__name__)
def test_a_map_takes_numpy_scalars_as_the_numbers_they_hold(wrap):
    assert CAL.rotor_speed(wrap(1500), wrap(12)) == CAL.rotor_speed(1500.0, 12.0)
    assert CAL.gimbal_pulse_us(wrap(1), GimbalMode.RATE) == CAL.gimbal_pulse_us(1.0, GimbalMode.RATE)


@pytest.mark.parametrize("bad", ["1000", b"1000", True, None, 10**5000], ids=lambda v: type(v).__name__)
def test_a_table_or_endpoint_that_is_no_number_is_a_calibration_error_naming_it(bad):
    with pytest.raises(CalibrationError) as caught:
        EscThrottleMap(low_us=bad)
    assert caught.value.where == "low_us" and len(str(caught.value)) < 200, caught.value
    with pytest.raises(CalibrationError) as caught:
        MonotoneCubic.pchip([0.0, bad, 2.0], [0.0, 1.0, 2.0])
    assert caught.value.where == "x[1]" and len(str(caught.value)) < 200, caught.value


@settings(max_examples=200, deadline=None)
@given(
    st.one_of(
        st.integers(),
        st.integers(0, 30_000).map(lambda n: 10**n),
        st.integers(0, 30_000).map(lambda n: -(10**n)),
        st.text(max_size=5000),
        st.binary(max_size=5000),
        st.lists(st.integers(0, 10_000).map(lambda n: 7**n), max_size=50),
    )
)
def test_an_error_shows_any_value_in_a_bounded_line(value):
    """Every :class:`FieldRangeError` can be built and stays a line, whatever value it carries."""
    exc = FieldRangeError("Msg", "field", value)
    assert exc.value is value
    assert len(value_repr(value)) <= 100 and len(str(exc)) <= 140, str(exc)


F32_IN_RANGE = st.floats(-100.0, 100.0, width=32)


@settings(max_examples=200, deadline=None)
@given(x=F32_IN_RANGE, wrap=st.sampled_from([np.float32, np.float64, np.array, float]))
def test_a_float_field_takes_numpy_scalars_as_the_float_they_hold(x, wrap):
    """numpy's float32 1.0 was refused as "out of range"; now each encodes as the plain float does, and
    decodes to it."""
    want = encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal=x, rotor_speed=x),)), 1)
    got = encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal=wrap(x), rotor_speed=wrap(x)),)), 1)
    assert got == want
    assert decode_frame(got[:-1]).message.units[0].gimbal == x


PROBE = textwrap.dedent(
    """
    import math, sys
    import numpy as np
    from protocol import speedups
    from protocol.errors import FieldRangeError
    from protocol.frame import encode_frame
    from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint
    values = [10**400, -(10**400), 10**5000, True, math.nan, -0.0, math.inf, 1e160, np.float32(1.0),
              np.float64(-0.0), np.int64(3), np.float32("nan"), np.array(1.0), "1.0", None, 3.4028235e38]
    print("native", speedups.NATIVE)
    for v in values:
        try:
            print("ok", encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal=v),)), 7).hex())
        except FieldRangeError as exc:
            print("refused", exc.field, str(exc))
    """
)


def test_the_c_and_the_pure_python_paths_judge_absurd_fields_alike():
    """Both codec paths, each in a real subprocess: the same frames and the same typed refusals, each a
    line naming the field (10**5000 was Python's own ValueError on both)."""
    outs = {}
    for pure in ("0", "1"):
        env = {**os.environ, "PROTOCOL_PURE": pure}
        done = subprocess.run(
            [sys.executable, "-c", PROBE], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, done.stderr[-2000:]
        first, *lines = done.stdout.splitlines()
        if pure == "1":
            assert first == "native False", first  # PROTOCOL_PURE=1: the pure-Python reference
        outs[pure] = lines
    assert outs["0"] == outs["1"]
    lines = outs["1"]
    assert len(lines) == 16
    refused = [line for line in lines if line.startswith("refused")]
    assert all("units[0].gimbal" in line and len(line) < 200 for line in refused), refused
    assert [line.split()[0] for line in lines] == (
        ["refused"] * 5 + ["ok"] + ["refused"] * 2 + ["ok"] * 3 + ["refused"] + ["ok"] + ["refused"] * 3
    )

"""A message's integer and enum fields, the pulse modules' integer widths and the servo limits take numpy's
integers as the ints they are (``protocol.numbers.whole_number``): a controller that computes its
pulses or counters in numpy arrays handed ``np.uint16(1500)`` to a ``u16`` field and was refused as "out
of range", though the same value as a Python int went out. What is no integer stays refused: numpy's
bool, a float holding a whole number, an integer past the field's range."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.errors import ConfigError, FieldRangeError
from protocol.frame import decode_frame, encode_frame
from protocol.messages import BoardState, Heartbeat, Telemetry
from protocol.numbers import whole_number
from protocol.pulse_widths import FINE_MAX, SigmaDelta, reported_us
from protocol.pulses import ServoParams

DTYPES = (np.uint8, np.uint16, np.uint32, np.int64, np.uint64, np.int32)
UNSIGNED_TOPS = {np.uint8: 0xFF, np.uint16: 0xFFFF, np.uint32: 0xFFFFFFFF}


@given(st.integers(-(2**70), 2**70), st.sampled_from(DTYPES + (None,)))
def test_whole_number_is_the_int_of_any_integer_and_none_of_anything_else(value, dtype):
    if dtype is None:
        assert whole_number(value) == value and type(whole_number(value)) is int
        return
    info = np.iinfo(dtype)
    if not info.min <= value <= info.max:
        return
    for held in (dtype(value), np.array(value, dtype=dtype)):
        got = whole_number(held)
        assert got == value and type(got) is int


@pytest.mark.parametrize(
    "value", [True, np.bool_(True), np.array(True), 3.0, np.float64(3.0), np.array(3.0), "3", None, 1j]
)
def test_whole_number_refuses_what_is_no_integer(value):
    assert whole_number(value) is None


@given(
    time_ms=st.integers(0, 0xFFFFFFFF),
    battery_mv=st.integers(0, 0xFFFF),
    soc=st.integers(0, 100),
    pulses=st.lists(st.integers(0, 2500), max_size=4),
    seq=st.integers(0, 0xFF),
)
def test_a_message_of_numpy_integers_goes_out_as_the_same_message_of_ints(
    time_ms, battery_mv, soc, pulses, seq
):
    as_ints = Telemetry(
        time_ms=time_ms,
        state=BoardState.ARMED,
        battery_mv=battery_mv,
        battery_soc=soc,
        pulses_us=tuple(pulses),
    )
    as_numpy = Telemetry(
        time_ms=np.uint32(time_ms),
        state=np.uint8(int(BoardState.ARMED)),
        battery_mv=np.uint16(battery_mv),
        battery_soc=np.int64(soc),
        pulses_us=tuple(np.array(pulses, dtype=np.uint16)),
    )
    wire = encode_frame(as_numpy, np.uint8(seq))
    assert wire == encode_frame(as_ints, seq)
    assert decode_frame(wire[:-1]).message == as_ints


@pytest.mark.parametrize(
    "field, value",
    [
        ("time_ms", np.int64(-1)),
        ("time_ms", np.uint64(2**32)),
        ("battery_soc", np.uint8(101)),
        ("battery_mv", np.bool_(True)),
        ("battery_mv", np.float64(3.0)),
        ("state", np.uint8(250)),  # no BoardState
    ],
)
def test_a_numpy_value_no_field_can_hold_is_refused_naming_the_field(field, value):
    with pytest.raises(FieldRangeError, match=field):
        encode_frame(Telemetry(**{field: value}), 0)


def test_the_header_sequence_takes_a_numpy_integer_and_refuses_one_past_a_byte():
    assert encode_frame(Heartbeat(time_ms=5), np.uint8(7)) == encode_frame(Heartbeat(time_ms=5), 7)
    with pytest.raises(FieldRangeError):
        encode_frame(Heartbeat(time_ms=5), np.uint16(256))


@given(st.lists(st.one_of(st.none(), st.integers(0, FINE_MAX)), min_size=1, max_size=8))
def test_the_dither_of_numpy_fine_widths_is_the_dither_of_ints(fine):
    ints, numpy_made = SigmaDelta(8), SigmaDelta(np.int64(8))
    held = [None if q is None else np.uint32(q) for q in fine]
    for _ in range(3):  # the remainders carry: they must stay the same over frames
        assert numpy_made.frame(held) == ints.frame(fine)
    assert numpy_made.residue == ints.residue
    assert all(type(r) is int for r in numpy_made.residue)
    for q in fine:
        if q is not None:
            assert reported_us(np.array(q)) == reported_us(q)


def test_servo_limits_take_numpy_integers_as_ints_and_refuse_numpy_floats():
    servo = ServoParams(min_us=np.uint16(1000), max_us=np.int64(2000))
    assert servo == ServoParams(1000, 2000) and type(servo.min_us) is int
    with pytest.raises(ConfigError, match="min_us"):
        ServoParams(min_us=np.float64(1000.0))

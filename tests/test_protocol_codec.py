"""The frame codec both ways for every message, range checks both ways, COBS, CRC and the Framer."""

from __future__ import annotations

import struct

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_protocol_strategies import (
    bad_value_strategy,
    flag_values,
    messages,
    raw_payload,
    record_strategy,
    seqs,
    wire_frames,
)

from protocol import cobs
from protocol.crc import crc16_ccitt_false
from protocol.errors import FieldRangeError, FrameError, ProtocolError
from protocol.fields import Array, Scalar, layout_of
from protocol.frame import (
    MAX_ENCODED,
    MAX_PAYLOAD,
    BadFrame,
    BadFrameReason,
    Deframer,
    Frame,
    Framer,
    decode_frame,
    encode_frame,
)
from protocol.messages import (
    CATALOGUE,
    MAX_UNITS,
    ActuatorSetpoint,
    Arm,
    Flags,
    Heartbeat,
    Hello,
    Telemetry,
    UnitSetpoint,
    UnitState,
)
from protocol.vectors import build_wire


# =========================================================================== message -> bytes -> message
@given(wire_frames())
def test_every_message_round_trips_through_the_wire(frame):
    msg, seq, flags, wire = frame
    assert wire.endswith(b"\x00") and wire.count(0) == 1
    assert len(wire) <= MAX_ENCODED + 1
    decoded = decode_frame(wire[:-1])
    assert decoded.message == msg
    assert (decoded.seq, int(decoded.flags)) == (seq, flags)
    assert type(decoded.message) is type(msg)


# =========================================================================== bytes -> message -> bytes
@given(messages(), seqs, flag_values)
def test_bytes_from_the_reference_encoder_decode_and_re_encode_identically(msg, seq, flags):
    """The other direction: wire bytes written independently of the codec decode to the message, and the
    decoded message encodes to the very same bytes."""
    wire = build_wire(msg.MSG_ID, raw_payload(msg), seq, flags)
    [event] = Deframer().feed(wire)
    assert isinstance(event, Frame)
    assert event.message == msg
    assert encode_frame(event.message, event.seq, int(event.flags)) == wire


@given(st.sampled_from(CATALOGUE), st.data())
def test_floats_survive_exactly_as_float32(cls, data):
    msg = data.draw(record_strategy(cls))
    again = decode_frame(encode_frame(msg, 0)[:-1]).message
    for name, codec in layout_of(cls).fields:
        if isinstance(codec, Scalar) and codec.fmt == "f":
            assert struct.pack("<f", getattr(again, name)) == struct.pack("<f", getattr(msg, name))


# =========================================================================== ranges, both ways
def _top_level_bad(cls):
    """(field, codec, bad-value strategy) of every top-level scalar/text field that can be out of range."""
    out = []
    for name, codec in layout_of(cls).fields:
        strategy = bad_value_strategy(codec)
        if strategy is not None:
            out.append((name, codec, strategy))
    return out


_BAD_FIELDS = [(cls, name, strategy) for cls in CATALOGUE for name, _, strategy in _top_level_bad(cls)]


@pytest.mark.parametrize(
    ("cls", "name", "bad"), _BAD_FIELDS, ids=[f"{c.__name__}.{n}" for c, n, _ in _BAD_FIELDS]
)
@settings(max_examples=15)
@given(data=st.data())
def test_out_of_range_is_refused_on_encode_and_reported_on_decode(cls, name, bad, data):
    msg = data.draw(record_strategy(cls))
    value = data.draw(bad)
    smuggled = _replace(msg, name, value)
    with pytest.raises(FieldRangeError) as info:
        encode_frame(smuggled, 0)
    assert (info.value.message_name, info.value.field) == (cls.__name__, name)
    # The same value put on the wire by a non-conforming sender (correct CRC):
    payload = raw_payload(msg, (name, value))
    [event] = Deframer().feed(build_wire(cls.MSG_ID, payload))
    assert isinstance(event, BadFrame)
    if len(payload) > MAX_PAYLOAD:  # an overlong text can push the frame past its size limit first
        assert event.reason is BadFrameReason.TOO_LONG
    else:
        assert event.reason is BadFrameReason.FIELD_RANGE
        assert name in event.detail


def _replace(msg, name, value):
    """A copy of a frozen message with one field set to anything (bypassing nothing but immutability)."""
    kwargs = {n: getattr(msg, n) for n, _ in layout_of(type(msg)).fields}
    kwargs[name] = value
    return type(msg)(**kwargs)


@given(st.integers(MAX_UNITS + 1, 255) | st.just(0))
def test_array_counts_out_of_range_both_ways(n):
    units = (UnitSetpoint(),) * n
    with pytest.raises(FieldRangeError) as info:
        encode_frame(ActuatorSetpoint(units=units), 0)
    assert "units" in info.value.field
    payload = raw_payload(ActuatorSetpoint(units=(UnitSetpoint(),)), ("units", units))
    [event] = Deframer().feed(build_wire(ActuatorSetpoint.MSG_ID, payload))
    expected = BadFrameReason.TOO_LONG if len(payload) > MAX_PAYLOAD else BadFrameReason.FIELD_RANGE
    assert isinstance(event, BadFrame) and event.reason is expected


@given(st.floats(allow_nan=True, allow_infinity=True, width=32).filter(lambda x: not abs(x) <= 20.0))
def test_a_bad_float_inside_an_array_record_is_refused_both_ways(rate):
    good = Telemetry(units=(UnitState(), UnitState()))
    bad_units = (UnitState(), UnitState(gimbal_rate=rate))
    with pytest.raises(FieldRangeError) as info:
        encode_frame(Telemetry(units=bad_units), 0)
    assert (info.value.message_name, info.value.field) == ("Telemetry.units[1]", "gimbal_rate")
    [event] = Deframer().feed(build_wire(Telemetry.MSG_ID, raw_payload(good, ("units", bad_units))))
    assert isinstance(event, BadFrame) and event.reason is BadFrameReason.FIELD_RANGE


def test_header_fields_and_types_are_checked_on_encode():
    with pytest.raises(FieldRangeError):
        encode_frame(Arm(), 256)
    with pytest.raises(FieldRangeError):
        encode_frame(Arm(), -1)
    with pytest.raises(FieldRangeError):
        encode_frame(Arm(), 0, flags=0x100)
    with pytest.raises(FieldRangeError):
        encode_frame(Heartbeat(time_ms=True), 0)  # a bool is not a u32
    with pytest.raises(FieldRangeError):
        encode_frame(Hello(manufacturer=b"bytes"), 0)  # text must be str
    with pytest.raises(FieldRangeError):
        encode_frame(ActuatorSetpoint(units=[UnitSetpoint()] * 2 + [UnitState()]), 0)


@given(messages(), seqs)
def test_truncated_or_extended_payloads_are_length_errors(msg, seq):
    payload = raw_payload(msg)
    extended = build_wire(msg.MSG_ID, payload + b"\x00", seq)
    [event] = Deframer().feed(extended)
    assert isinstance(event, BadFrame) and event.reason is BadFrameReason.LENGTH
    if payload:
        [event] = Deframer().feed(build_wire(msg.MSG_ID, payload[:-1], seq))
        assert isinstance(event, BadFrame)
        # Cutting the last byte usually ends the payload inside a field; it can also leave a count that
        # now claims too much, or a shorter text that is no longer valid UTF-8.
        assert event.reason in (BadFrameReason.LENGTH, BadFrameReason.FIELD_RANGE)


@given(st.integers(1, 255).filter(lambda v: v != 1), st.sampled_from(CATALOGUE))
def test_other_versions_are_refused(version, cls):
    [event] = Deframer().feed(build_wire(cls.MSG_ID, b"", version=version))
    assert isinstance(event, BadFrame) and event.reason is BadFrameReason.VERSION


@given(st.integers(0, 255).filter(lambda i: i not in {c.MSG_ID for c in CATALOGUE}))
def test_unknown_ids_are_refused(msg_id):
    [event] = Deframer().feed(build_wire(msg_id, b"\x01\x02"))
    assert isinstance(event, BadFrame) and event.reason is BadFrameReason.UNKNOWN_ID


def test_decode_frame_raises_typed_errors_with_the_reason():
    with pytest.raises(FrameError) as info:
        decode_frame(b"\x05\x01")
    assert info.value.reason is BadFrameReason.COBS
    assert isinstance(info.value, ProtocolError) and isinstance(info.value, ValueError)


# =========================================================================== COBS and CRC
@given(st.binary(max_size=1200))
def test_cobs_round_trip_and_no_zero(data):
    encoded = cobs.encode(data)
    assert 0 not in encoded
    assert len(encoded) <= cobs.max_encoded_len(len(data))
    assert cobs.decode(encoded) == data


@given(st.binary(min_size=1, max_size=600).filter(lambda b: 0 not in b))
def test_cobs_decode_never_crashes_on_garbage(data):
    try:
        out = cobs.decode(data)
    except FrameError as exc:
        assert exc.reason is BadFrameReason.COBS
    else:
        assert len(out) < len(data)


def test_crc_check_value_and_incremental_use():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false(b"56789", crc16_ccitt_false(b"1234")) == 0x29B1


@given(st.binary(min_size=1, max_size=256), st.data())
def test_crc_detects_every_single_bit_error(data, draw):
    bit = draw.draw(st.integers(0, 8 * len(data) - 1))
    flipped = bytearray(data)
    flipped[bit // 8] ^= 1 << (bit % 8)
    assert crc16_ccitt_false(bytes(flipped)) != crc16_ccitt_false(data)


# =========================================================================== Framer
@given(seqs, st.lists(messages(), min_size=1, max_size=30))
def test_framer_numbers_frames_and_flags_reliable_ones(first, msgs):
    framer = Framer(first)
    for i, msg in enumerate(msgs):
        seq, wire = framer.encode(msg)
        assert seq == (first + i) % 256
        frame = decode_frame(wire[:-1])
        assert frame.seq == seq
        assert bool(frame.flags & Flags.ACK_REQUESTED) == type(msg).RELIABLE
        assert not frame.flags & Flags.RETRANSMIT


def test_framer_retry_keeps_the_sequence_number_and_marks_retransmit():
    framer = Framer(254)
    seq, first = framer.encode(Arm())
    assert seq == 254
    _, retry = framer.encode(Arm(), seq=seq)
    assert framer.next_seq == 255  # a retry takes no new number
    a, b = decode_frame(first[:-1]), decode_frame(retry[:-1])
    assert (a.seq, b.seq) == (254, 254)
    assert a.flags == Flags.ACK_REQUESTED
    assert b.flags == Flags.ACK_REQUESTED | Flags.RETRANSMIT
    framer.encode(Arm())
    assert framer.encode(Arm())[0] == 0  # wraps


@given(seqs, st.lists(messages(), min_size=1, max_size=30))
def test_a_prepared_message_is_sent_as_the_same_bytes_as_an_encoded_one(first, msgs):
    """Framer.prepare encodes once (a setpoint checked when given, sent at its slot); send_prepared numbers
    it: the wire bytes are encode()'s, and a prepared message never sent takes no number."""
    encoding, preparing = Framer(first), Framer(first)
    for msg in msgs:
        body = preparing.prepare(msg)
        preparing.prepare(msg)  # prepared and dropped (a coalesced setpoint): no number used
        assert preparing.send_prepared(body) == encoding.encode(msg)
    assert preparing.next_seq == encoding.next_seq


def test_array_records_are_records():
    for cls in CATALOGUE:
        for _, codec in layout_of(cls).fields:
            if isinstance(codec, Array) and not isinstance(codec.item, Scalar):
                assert layout_of(codec.item).fixed_size > 0


def test_a_frame_that_fails_to_encode_uses_no_sequence_number():
    """Regression: the Framer took the number before encoding, so a refused message left a gap that the
    receiver counted as a lost frame."""
    framer = Framer(10)
    with pytest.raises(FieldRangeError):
        framer.encode(Heartbeat(time_ms=-1))
    assert framer.next_seq == 10
    deframer = Deframer()
    deframer.feed(framer.encode(Heartbeat(time_ms=1))[1] + framer.encode(Heartbeat(time_ms=2))[1])
    assert deframer.counters.frames == 2 and deframer.counters.seq_gaps == 0


@given(st.binary(max_size=600).map(lambda b: b.replace(b"\x00", b"\x01")))
def test_cobs_fast_decoder_agrees_with_the_general_one(data):
    """The in-place decoder (taken when no 0xFF byte can start a full block) against the general one."""

    def outcome(fn):
        try:
            return fn(data)
        except FrameError as exc:
            return exc.detail

    assert outcome(cobs.decode) == outcome(cobs._decode_with_full_blocks)


def test_scalars_of_a_neighbouring_type_take_the_full_check():
    """The encoder's fast path accepts exact int/float; anything else goes through the field's check."""
    frame = decode_frame(
        encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal=1, rotor_speed=-2),)), 0)[:-1]
    )
    assert frame.message.units[0] == UnitSetpoint(gimbal=1.0, rotor_speed=-2.0)
    for bad in (True, "1.0", None, float("nan"), float("inf")):
        with pytest.raises(FieldRangeError):
            encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal=bad),)), 0)
    with pytest.raises(FieldRangeError):
        encode_frame(Heartbeat(time_ms=1.0), 0)  # a float in an integer field

"""The generated per-message codecs (``protocol.compiled``) against the layout interpreter they are built
from (``Layout.encode_into`` / ``decode_from``, the reference that words every error): the same bytes for
every valid message, the same message for every payload the reference accepts, and ``None`` (the way to
the reference) for everything it refuses."""

from __future__ import annotations

import dataclasses
import math
import random

import hypothesis.strategies as st
import pytest
from hypothesis import assume, given, settings
from test_protocol_strategies import bad_value_strategy, messages, raw_payload, record_strategy, seqs

from protocol.compiled import STRUCT_CACHE, compile_message, fast_constructor
from protocol.errors import FieldRangeError, ProtocolError
from protocol.fields import Array, PayloadLengthError, Scalar, layout_of
from protocol.frame import HEADER, decode_frame, encode_frame
from protocol.messages import (
    CATALOGUE,
    CODECS,
    LAYOUTS,
    PROTOCOL_VERSION,
    ActuatorSetpoint,
    ControlMode,
    FaultFlag,
    GimbalMode,
    Hello,
    SetMode,
    Telemetry,
    UnitSetpoint,
    UnitState,
)


def _reference_encode(msg) -> bytes | None:
    out = bytearray()
    try:
        LAYOUTS[msg.MSG_ID].encode_into(msg, out, type(msg).__name__)
    except FieldRangeError:
        return None
    return bytes(out)


def _reference_decode(msg_id: int, payload: bytes):
    layout = LAYOUTS[msg_id]
    try:
        msg, end = layout.decode_from(payload, 0, layout.name)
    except (PayloadLengthError, FieldRangeError):
        return None
    return msg if end == len(payload) else None


def _body(msg_id: int, payload: bytes, seq: int = 0, flags: int = 0) -> bytes:
    return HEADER.pack(PROTOCOL_VERSION, msg_id, seq, flags) + payload


def test_every_message_has_a_generated_codec():
    assert set(CODECS) == {cls.MSG_ID for cls in CATALOGUE}
    for cls in CATALOGUE:
        codec = CODECS[cls.MSG_ID]
        assert "def encode(m, seq, flags):" in codec.source and "def decode(b):" in codec.source


# =========================================================================== valid messages
@settings(max_examples=300)
@given(messages(), seqs, st.integers(0, 3))
def test_encode_is_the_reference_byte_for_byte_and_decode_inverts_it(msg, seq, flags):
    codec = CODECS[msg.MSG_ID]
    body = codec.encode(msg, seq, flags)
    assert body == _body(msg.MSG_ID, _reference_encode(msg), seq, flags)
    decoded = codec.decode(body)
    assert decoded == msg == _reference_decode(msg.MSG_ID, body[4:])
    assert type(decoded) is type(msg) and hash(decoded) == hash(msg) and repr(decoded) == repr(msg)
    assert all(type(getattr(decoded, n)) is type(getattr(msg, n)) for n, _ in layout_of(type(msg)).fields)


def test_decoded_messages_are_as_frozen_as_constructed_ones():
    msg = CODECS[ActuatorSetpoint.MSG_ID].decode(encode_frame_body(ActuatorSetpoint(units=(UnitSetpoint(),))))
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.gimbal_mode = GimbalMode.ANGLE
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.units[0].gimbal = 1.0


def encode_frame_body(msg) -> bytes:
    return CODECS[msg.MSG_ID].encode(msg, 0, 0)


# =========================================================================== anything on the wire
@st.composite
def damaged_payloads(draw: st.DrawFn) -> tuple[int, bytes]:
    """A message id and a payload near a valid one: bytes flipped (counts included), cut or extended."""
    msg = draw(messages())
    payload = bytearray(raw_payload(msg))
    for _ in range(draw(st.integers(0, 3))):
        if payload:
            payload[draw(st.integers(0, len(payload) - 1))] = draw(st.integers(0, 255))
    cut = draw(st.integers(0, len(payload)))
    tail = draw(st.binary(max_size=4)) if draw(st.booleans()) else b""
    return msg.MSG_ID, bytes(payload[:cut] if draw(st.booleans()) else payload) + tail


@settings(max_examples=600)
@given(damaged_payloads() | st.tuples(st.sampled_from(sorted(CODECS)), st.binary(max_size=80)))
def test_decode_takes_exactly_what_the_reference_takes(case):
    msg_id, payload = case
    fast = CODECS[msg_id].decode(_body(msg_id, payload))
    reference = _reference_decode(msg_id, payload)
    assert fast == reference
    if reference is not None:
        assert type(fast) is type(reference)


_ITEMS = [  # (message, array field, item field or "" for an array of scalars, the item's codec)
    (cls, name, item_name, item_codec)
    for cls in CATALOGUE
    for name, codec in layout_of(cls).fields
    if isinstance(codec, Array)
    for item_name, item_codec in (
        [("", codec.item)] if isinstance(codec.item, Scalar) else layout_of(codec.item).fields
    )
    if bad_value_strategy(item_codec) is not None
]


@pytest.mark.parametrize(
    ("cls", "name", "item_name", "item_codec"), _ITEMS, ids=[f"{c.__name__}.{n}.{i}" for c, n, i, _ in _ITEMS]
)
@settings(max_examples=25)
@given(data=st.data())
def test_a_bad_value_in_any_array_item_is_refused_both_ways(cls, name, item_name, item_codec, data):
    """NaN, infinities and out-of-range values anywhere in an array, put on the wire by a non-conforming
    sender: the decoder refuses them (as the reference does) and so does the encoder."""
    msg = data.draw(record_strategy(cls))
    items = list(getattr(msg, name))
    assume(items)
    i = data.draw(st.integers(0, len(items) - 1))
    bad = data.draw(bad_value_strategy(item_codec))
    items[i] = bad if not item_name else dataclasses.replace(items[i], **{item_name: bad})
    smuggled = tuple(items)
    payload = raw_payload(msg, (name, smuggled))
    assert CODECS[cls.MSG_ID].decode(_body(cls.MSG_ID, payload)) is None
    assert _reference_decode(cls.MSG_ID, payload) is None
    assert CODECS[cls.MSG_ID].encode(dataclasses.replace(msg, **{name: smuggled}), 0, 0) is None


# =========================================================================== anything in a message
_SCALARS = [
    (cls, name, codec)
    for cls in CATALOGUE
    for name, codec in layout_of(cls).fields
    if bad_value_strategy(codec) is not None
]


@pytest.mark.parametrize(
    ("cls", "name", "codec"), _SCALARS, ids=[f"{c.__name__}.{n}" for c, n, _ in _SCALARS]
)
@settings(max_examples=10)
@given(data=st.data())
def test_out_of_range_values_go_to_the_reference(cls, name, codec, data):
    msg = data.draw(record_strategy(cls))
    bad = dataclasses.replace(msg, **{name: data.draw(bad_value_strategy(codec))})
    assert CODECS[cls.MSG_ID].encode(bad, 0, 0) is None
    with pytest.raises(FieldRangeError) as info:
        encode_frame(bad, 0)
    assert info.value.field == name


_NEIGHBOURS = [  # values of a neighbouring type: the reference takes the first four, refuses the rest
    Telemetry(faults=FaultFlag.DEAD_ESC | FaultFlag.LINK_LOST),  # an IntFlag in a u16
    Telemetry(state=2, pulses_us=[1500, 1500]),  # a plain int for an enum, a list for a tuple
    ActuatorSetpoint(units=(UnitSetpoint(gimbal=1, rotor_speed=-2),)),  # ints in float fields
    SetMode(mode=1),
    Telemetry(time_ms=True),  # a bool is not a u32
    Telemetry(time_ms=1 << 32),  # outside the wire type itself (struct's own check)
    Telemetry(time_ms=-1),
    Telemetry(battery_soc=101),
    Telemetry(units=(UnitState(gimbal_rate=math.nan),)),
    Telemetry(units=(UnitSetpoint(),)),  # the wrong record class
    ActuatorSetpoint(units=(UnitSetpoint(),) * 9),
    SetMode(mode=ControlMode.RAW_PULSES.value + 7),
    Hello(manufacturer="\ud800"),  # a lone surrogate is not UTF-8
    Hello(manufacturer="é" * 13),  # 26 bytes > 24
    Hello(manufacturer=b"bytes"),
]


@pytest.mark.parametrize("msg", _NEIGHBOURS, ids=range(len(_NEIGHBOURS)))
def test_values_the_fast_path_does_not_take_are_the_reference_s_to_judge(msg):
    assert CODECS[msg.MSG_ID].encode(msg, 0, 0) is None
    reference = _reference_encode(msg)
    if reference is None:
        with pytest.raises(ProtocolError):
            encode_frame(msg, 0)
    else:  # encoded as before, and it decodes to the canonical values
        wire = encode_frame(msg, 3)
        assert wire == encode_frame(decode_frame(wire[:-1]).message, 3)


# =========================================================================== the struct cache
def test_the_struct_cache_is_bounded_whatever_counts_arrive():
    """Hello has six texts: far more combinations of their lengths than the cache keeps."""
    codec = compile_message(Hello, Hello.MSG_ID, PROTOCOL_VERSION)
    rng = random.Random(5)
    for _ in range(3 * STRUCT_CACHE):
        msg = Hello(**{n: "x" * rng.randrange(0, 17) for n in ("manufacturer", "model", "version", "uri")})
        assert codec.decode(codec.encode(msg, 0, 0)) == msg
        assert len(codec.decode.__globals__["STRUCTS"]) <= STRUCT_CACHE


# =========================================================================== construction by slots
def test_fast_construction_only_for_frozen_slotted_dataclasses_without_post_init():
    point = fast_constructor(UnitState)(1.0, 2.0, 3.0)
    assert point == UnitState(1.0, 2.0, 3.0)

    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        x: int

        def __post_init__(self) -> None:
            raise AssertionError

    @dataclasses.dataclass(slots=True)
    class Mutable:
        x: int

    @dataclasses.dataclass(frozen=True)
    class NoSlots:
        x: int

    for cls in (Checked, Mutable, NoSlots, int):
        with pytest.raises(TypeError):
            fast_constructor(cls)

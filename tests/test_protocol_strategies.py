"""Hypothesis strategies for the protocol, derived from the field codecs (so a new message or field is
covered without touching the tests), an independent reference encoder that skips range checks (to put
out-of-range values on the wire), and the tests that keep both honest.

Other ``test_protocol_*`` modules import from here.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import hypothesis.strategies as st
import pytest
from hypothesis import given

from protocol.fields import (  # the wire types' own bounds
    _INT_BOUNDS,
    Array,
    Blob,
    Enum8,
    Scalar,
    Text,
    layout_of,
)
from protocol.frame import MAX_PAYLOAD, Framer, encode_frame
from protocol.messages import CATALOGUE, Flags, encode_payload
from protocol.vectors import payload_size_range


# =========================================================================== valid values
def value_strategy(codec: Any) -> st.SearchStrategy[Any]:
    """Every value ``codec`` accepts (and nothing else)."""
    if isinstance(codec, Enum8):
        return st.sampled_from(list(codec.enum_cls))
    if isinstance(codec, Scalar):
        if codec.fmt == "f":
            return st.floats(codec.lo, codec.hi, width=32, allow_nan=False, allow_infinity=False)
        return st.integers(int(codec.lo), int(codec.hi))
    if isinstance(codec, Text):
        return st.text(max_size=codec.max_len).map(lambda s, n=codec.max_len: _truncate_utf8(s, n))
    if isinstance(codec, Blob):
        return st.binary(max_size=codec.max_len)
    assert isinstance(codec, Array)
    item = value_strategy(codec.item) if isinstance(codec.item, Scalar) else record_strategy(codec.item)
    return st.lists(item, min_size=codec.min_count, max_size=codec.max_count).map(tuple)


def _truncate_utf8(text: str, limit: int) -> str:
    return text.encode("utf-8")[:limit].decode("utf-8", "ignore")


def record_strategy(cls: type) -> st.SearchStrategy[Any]:
    """Instances of a wire dataclass (message or record) with every field in range."""
    return st.builds(cls, **{name: value_strategy(codec) for name, codec in layout_of(cls).fields})


def messages(classes: tuple[type, ...] = CATALOGUE) -> st.SearchStrategy[Any]:
    """Any valid message of ``classes`` (default: the whole catalogue) that fits in one frame."""
    return (
        st.sampled_from(classes)
        .flatmap(record_strategy)
        .filter(lambda m: len(encode_payload(m)) <= MAX_PAYLOAD)
    )


seqs = st.integers(0, 255)
flag_values = st.sampled_from([0, int(Flags.ACK_REQUESTED), int(Flags.RETRANSMIT), 3])


@st.composite
def wire_frames(draw: st.DrawFn, classes: tuple[type, ...] = CATALOGUE) -> tuple[Any, int, int, bytes]:
    """``(message, seq, flags, wire bytes)``."""
    msg, seq, flags = draw(messages(classes)), draw(seqs), draw(flag_values)
    return msg, seq, flags, encode_frame(msg, seq, flags)


@st.composite
def numbered_stream(draw: st.DrawFn, max_frames: int = 12) -> list[tuple[Any, bytes]]:
    """Consecutive frames from one Framer: ``[(message, wire), ...]``."""
    framer = Framer(draw(seqs))
    return [(m, framer.encode(m)[1]) for m in draw(st.lists(messages(), min_size=1, max_size=max_frames))]


# =========================================================================== out-of-range values
def bad_value_strategy(codec: Any) -> st.SearchStrategy[Any] | None:
    """Values of ``codec``'s wire type that its range refuses (None: the wire type cannot hold one)."""
    if isinstance(codec, Enum8):
        valid = {int(m) for m in codec.enum_cls}
        return st.integers(0, 255).filter(lambda v: v not in valid)
    if isinstance(codec, Scalar):
        if codec.fmt == "f":
            outside = st.floats(width=32, allow_nan=False).filter(lambda x: not codec.lo <= x <= codec.hi)
            return st.one_of(st.just(math.nan), st.just(math.inf), st.just(-math.inf), outside)
        tlo, thi = _INT_BOUNDS[codec.fmt]
        parts = []
        if codec.lo > tlo:
            parts.append(st.integers(tlo, int(codec.lo) - 1))
        if codec.hi < thi:
            parts.append(st.integers(int(codec.hi) + 1, thi))
        return st.one_of(parts) if parts else None
    if isinstance(codec, Text):
        if codec.max_len >= 255:
            return None
        return st.integers(codec.max_len + 1, 255).map(lambda n: "x" * n)
    return None


# =========================================================================== reference encoder
def raw_payload(obj: Any, override: tuple[str, Any] | None = None) -> bytes:
    """The payload of ``obj`` written field by field with ``struct``, *without* range checks; ``override``
    = (field name, value) replaces one top-level field's value (or, for an array field, the whole tuple).

    Independent of ``Layout`` on purpose: it is the reference the codec is compared against."""
    out = bytearray()
    for name, codec in layout_of(type(obj)).fields:
        value = override[1] if override is not None and override[0] == name else getattr(obj, name)
        _raw_field(codec, value, out)
    return bytes(out)


def _raw_field(codec: Any, value: Any, out: bytearray) -> None:
    if isinstance(codec, Scalar):
        out += struct.pack("<" + codec.fmt, int(value) if codec.fmt != "f" else value)
    elif isinstance(codec, Text):
        raw = value.encode("utf-8")
        out.append(len(raw))
        out += raw
    elif isinstance(codec, Blob):
        out.append(len(value))
        out += value
    else:
        out.append(len(value))
        for item in value:
            if isinstance(codec.item, Scalar):
                _raw_field(codec.item, item, out)
            else:
                out += raw_payload(item)


# =========================================================================== the strategies' own tests
@given(messages())
def test_reference_encoder_agrees_with_the_codec(msg):
    assert raw_payload(msg) == encode_payload(msg)


@pytest.mark.parametrize("cls", CATALOGUE, ids=lambda c: c.__name__)
def test_payload_size_range_is_reached_by_extreme_messages(cls):
    """The catalogue's size ranges (used by the doc and the vectors) match the smallest and largest
    message the codecs allow."""
    lo, hi = payload_size_range(cls)
    assert len(encode_payload(extreme_message(cls, largest=False))) == lo
    assert len(encode_payload(extreme_message(cls, largest=True))) == hi
    assert hi <= MAX_PAYLOAD


def extreme_message(cls: type, largest: bool) -> Any:
    """The smallest or largest instance of ``cls`` on the wire (every text, blob and array at its limit)."""
    kwargs = {}
    for name, codec in layout_of(cls).fields:
        if isinstance(codec, Enum8):
            kwargs[name] = next(iter(codec.enum_cls))
        elif isinstance(codec, Scalar):
            kwargs[name] = codec.lo if codec.fmt == "f" else int(codec.lo)
        elif isinstance(codec, Text):
            kwargs[name] = "x" * codec.max_len if largest else ""
        elif isinstance(codec, Blob):
            kwargs[name] = b"x" * codec.max_len if largest else b""
        else:
            n = codec.max_count if largest else codec.min_count
            item = codec.item
            one = (
                (int(item.lo) if item.fmt != "f" else item.lo)
                if isinstance(item, Scalar)
                else extreme_message(item, largest)
            )
            kwargs[name] = (one,) * n
    return cls(**kwargs)


@pytest.mark.parametrize("cls", CATALOGUE, ids=lambda c: c.__name__)
def test_every_field_has_a_strategy_and_every_bounded_field_a_bad_value(cls):
    for name, codec in layout_of(cls).fields:
        assert value_strategy(codec) is not None, name
        if isinstance(codec, Scalar) and (codec.fmt == "f" or isinstance(codec, Enum8)):
            assert bad_value_strategy(codec) is not None, name  # floats and enums can always be wrong

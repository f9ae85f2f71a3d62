"""Beside the tested AOA start sequence (six strings an ``AccessoryIdentity`` has checked): ``send_string``
and ``ControlTransfer`` given directly what parses but the phone cannot take. ``send_string`` checked
nothing: a lone surrogate raised ``UnicodeEncodeError``; a NUL inside, 64 KiB of text (a ``wLength`` past
u16) or an index of 6 or -1 built a transfer the phone cuts short or refuses, or pyusb fails on with its
own error at the moment of the transfer; a ``ControlTransfer`` took any field (negative, past u8/u16, an
OUT transfer whose ``wLength`` is not its data's length). Each is a FieldRangeError naming the field now,
checked as ``AccessoryIdentity`` checks its strings."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings

from protocol.aoa import (
    ACC_STRING_SIZE,
    REQUEST_TYPE_VENDOR_IN,
    REQUEST_TYPE_VENDOR_OUT,
    AccessoryIdentity,
    ControlTransfer,
    Request,
    StringIndex,
    send_string,
)
from protocol.errors import FieldRangeError

ABSURD_TEXT = st.sampled_from(
    ["", "\x00", "a\x00b", "x" * 255, "x" * 256, "x" * 65535, "é" * 127, "é" * 128, "\udcff", "\U0001f6f0"]
)
ANY_TEXT = st.text(st.characters(exclude_categories=()), max_size=300)


@settings(max_examples=300, deadline=None)
@given(index=st.one_of(st.integers(-2, 8), st.sampled_from(list(StringIndex))), text=ANY_TEXT | ABSURD_TEXT)
@example(index=StringIndex.VERSION, text="\udcff")
@example(index=StringIndex.URI, text="x" * 65535)
@example(index=StringIndex.MODEL, text="a\x00b")
@example(index=6, text="serial")
def test_send_string_builds_only_what_the_phone_takes_else_names_the_string(index, text):
    as_identity_field = None
    if 0 <= index <= 5:
        name = StringIndex(index).name.lower()
        try:
            AccessoryIdentity(**{"manufacturer": "m", "model": "m", name: text})
        except FieldRangeError:
            as_identity_field = "refused"
    try:
        transfer = send_string(index, text)
    except FieldRangeError as refused:
        if not 0 <= index <= 5:
            assert refused.field == "wIndex" and refused.message_name == "SEND_STRING"
        else:
            assert as_identity_field == "refused"  # the one check, shared with AccessoryIdentity
            assert refused.field.startswith(StringIndex(index).name.lower())
        return
    assert 0 <= index <= 5 and as_identity_field is None
    assert (transfer.bmRequestType, transfer.bRequest, transfer.wValue, transfer.wIndex) == (
        REQUEST_TYPE_VENDOR_OUT,
        Request.SEND_STRING,
        0,
        index,
    )
    assert transfer.data[-1:] == b"\x00" and b"\x00" not in transfer.data[:-1]
    assert transfer.data[:-1].decode("utf-8") == text  # what the phone reads back up to the terminator
    assert transfer.wLength == len(transfer.data) <= ACC_STRING_SIZE


U8_FIELDS = ("bmRequestType", "bRequest")
U16_FIELDS = ("wValue", "wIndex", "wLength")
SETUP_VALUE = st.one_of(
    st.integers(-1, 0x10000), st.sampled_from([-(2**63), 2**64, True, 1.0, None, "1", 0xFF, 0x100])
)


@settings(max_examples=300, deadline=None)
@given(field=st.sampled_from(U8_FIELDS + U16_FIELDS), value=SETUP_VALUE, request_in=st.booleans())
def test_a_control_transfer_usb_cannot_carry_is_refused_naming_its_field(field, value, request_in):
    base = {
        "bmRequestType": REQUEST_TYPE_VENDOR_IN if request_in else REQUEST_TYPE_VENDOR_OUT,
        "bRequest": 51,
    }
    base.update({"wValue": 0, "wIndex": 0, "wLength": 0})
    kwargs = {**base, field: value}
    top = 0xFF if field in U8_FIELDS else 0xFFFF
    fits = type(value) is int and 0 <= value <= top
    if fits and field == "wLength" and not kwargs["bmRequestType"] & 0x80:
        fits = value == 0  # OUT: wLength is its data's length (none here)
    if not fits:
        with pytest.raises(FieldRangeError) as info:
            ControlTransfer(**kwargs)
        assert info.value.message_name == "ControlTransfer" and info.value.field.startswith(field)
        return
    transfer = ControlTransfer(**kwargs)
    assert getattr(transfer, field) == value


def test_data_belongs_to_out_transfers_and_sets_their_length():
    with pytest.raises(FieldRangeError, match="IN transfers carry none"):
        ControlTransfer(REQUEST_TYPE_VENDOR_IN, 51, 0, 0, data=b"\x01\x00", wLength=2)
    with pytest.raises(FieldRangeError, match="wLength"):
        ControlTransfer(REQUEST_TYPE_VENDOR_OUT, 52, 0, 0, data=b"ab\x00", wLength=2)
    with pytest.raises(FieldRangeError, match="data"):
        ControlTransfer(REQUEST_TYPE_VENDOR_OUT, 52, 0, 0, data="ab", wLength=2)  # type: ignore[arg-type]
    assert ControlTransfer(REQUEST_TYPE_VENDOR_OUT, 52, 0, 1, b"ab\x00", 3).data_or_length == b"ab\x00"
    assert ControlTransfer(REQUEST_TYPE_VENDOR_IN, 51, 0, 0, wLength=2).data_or_length == 2

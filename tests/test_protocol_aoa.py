"""The Android Open Accessory start sequence and accessory-mode ids, value by value (checked against
the Linux kernel's f_accessory.h and the AOA 1.0/2.0 documentation)."""

from __future__ import annotations

import pytest

from protocol.aoa import (
    ACC_STRING_SIZE,
    ACCESSORY_INTERFACE,
    GOOGLE_VID,
    AccessoryIdentity,
    AccessoryPid,
    Request,
    StringIndex,
    accessory_interfaces,
    is_accessory_mode,
    parse_protocol_version,
    start_sequence,
)
from protocol.errors import FieldRangeError, ProtocolError
from protocol.messages import Hello, HelloReply

IDENTITY = AccessoryIdentity(
    manufacturer="vscmg-hil",
    model="ADK-VSCMG",
    description="VSCMG ADCS board",
    version="1.0",
    uri="https://example.invalid/vscmg-hil",
    serial="SIM0001",
)


def test_start_sequence_is_get_protocol_six_strings_then_start():
    seq = start_sequence(IDENTITY)
    assert [(t.bmRequestType, t.bRequest, t.wValue, t.wIndex) for t in seq] == [
        (0xC0, 51, 0, 0),
        (0x40, 52, 0, 0),
        (0x40, 52, 0, 1),
        (0x40, 52, 0, 2),
        (0x40, 52, 0, 3),
        (0x40, 52, 0, 4),
        (0x40, 52, 0, 5),
        (0x40, 53, 0, 0),
    ]
    get, *strings, start = seq
    assert get.is_in and get.wLength == 2 and get.data_or_length == 2
    assert [t.data for t in strings] == [
        b"vscmg-hil\x00",
        b"ADK-VSCMG\x00",
        b"VSCMG ADCS board\x00",
        b"1.0\x00",
        b"https://example.invalid/vscmg-hil\x00",
        b"SIM0001\x00",
    ]
    assert all(not t.is_in and t.wLength == len(t.data) and t.data_or_length == t.data for t in strings)
    assert not start.is_in and start.data == b"" and start.wLength == 0
    assert (Request.GET_PROTOCOL, Request.SEND_STRING, Request.START) == (51, 52, 53)
    assert [int(i) for i in StringIndex] == [0, 1, 2, 3, 4, 5]


def test_identity_comes_from_the_handshake_messages():
    reply = HelloReply(manufacturer="M", model="m", description="d", version="v", uri="u", serial="s")
    assert AccessoryIdentity.from_message(reply) == AccessoryIdentity("M", "m", "d", "v", "u", "s")
    hello = Hello(manufacturer="Ü", model="phone")
    data = start_sequence(AccessoryIdentity.from_message(hello))[1].data
    assert data == "Ü".encode() + b"\x00"  # UTF-8, zero-terminated


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("model", "a\x00b"),
        ("serial", "x" * ACC_STRING_SIZE),
        ("uri", "é" * 128),
        ("version", "\udcff"),
        ("model", 5),
    ],
)
def test_identity_strings_the_phone_cannot_take_are_refused(field, value):
    kwargs = {"manufacturer": "m", "model": "m", field: value}
    with pytest.raises(FieldRangeError) as info:
        AccessoryIdentity(**kwargs)
    assert info.value.field.startswith(field)
    AccessoryIdentity(**{**kwargs, field: "x" * (ACC_STRING_SIZE - 1)})  # 255 bytes + NUL is the limit


def test_protocol_version_answer():
    assert parse_protocol_version(b"\x01\x00") == 1
    assert parse_protocol_version(bytearray(b"\x02\x00")) == 2
    with pytest.raises(ProtocolError, match="does not support"):
        parse_protocol_version(b"\x00\x00")
    with pytest.raises(ProtocolError, match="expected 2"):
        parse_protocol_version(b"\x01")


def test_accessory_mode_ids_and_interfaces():
    assert GOOGLE_VID == 0x18D1 and ACCESSORY_INTERFACE == 0
    assert [int(p) for p in AccessoryPid] == [0x2D00, 0x2D01, 0x2D02, 0x2D03, 0x2D04, 0x2D05]
    table = {
        0x2D00: (True, False, False, 1),
        0x2D01: (True, True, False, 1),
        0x2D02: (False, False, True, 2),
        0x2D03: (False, True, True, 2),
        0x2D04: (True, False, True, 2),
        0x2D05: (True, True, True, 2),
    }
    for pid, expected in table.items():
        assert is_accessory_mode(0x18D1, pid)
        i = accessory_interfaces(0x18D1, pid)
        assert (i.accessory, i.adb, i.audio, i.min_aoa_version) == expected
    for vid, pid in ((0x18D1, 0x4EE7), (0x18D1, 0x2D06), (0x04E8, 0x2D00), (0x18D1, 0x2CFF)):
        assert not is_accessory_mode(vid, pid)
        with pytest.raises(ProtocolError, match="not an Android accessory"):
            accessory_interfaces(vid, pid)

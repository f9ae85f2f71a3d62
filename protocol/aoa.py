"""Android Open Accessory (AOA) as data: the USB control transfers that switch a phone into accessory
mode, and the USB ids it then enumerates with. Sans-IO: a USB transport (e.g. pyusb's
``dev.ctrl_transfer(t.bmRequestType, t.bRequest, t.wValue, t.wIndex, t.data_or_length)``) performs them.

In the paper's set-up the ADK board is the USB *host* and the phone the USB *device*; whoever plays the
host (the board, or a PC with pyusb standing in for it) runs, against a phone in its normal mode:

1. ``GET_PROTOCOL`` (vendor IN request 51): 2 bytes back, the AOA version, little-endian u16
   (0 = no AOA support, 1 = AOA 1.0, 2 = AOA 2.0 which adds audio and HID);
2. ``SEND_STRING`` (vendor OUT request 52) six times, ``wIndex`` 0..5 = manufacturer, model, description,
   version, URI, serial, each a zero-terminated UTF-8 string (at most 256 bytes with the terminator);
3. ``START`` (vendor OUT request 53): the phone drops off the bus and re-enumerates as vendor 0x18D1
   (Google) with a product id 0x2D00..0x2D05 that says which interfaces it now has.

The same six strings are the identity strings of this protocol's ``Hello``/``HelloReply`` (the phone's
app matches accessories by manufacturer, model and version). Values checked against the Linux kernel's
``include/uapi/linux/usb/f_accessory.h`` and the AOA 1.0/2.0 documentation.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields
from typing import Any

from .errors import FieldRangeError, ProtocolError

GOOGLE_VID = 0x18D1
"""USB vendor id a phone uses in accessory mode."""
ACC_STRING_SIZE = 256
"""Longest identity string the phone's gadget driver stores, terminator included."""
ACCESSORY_INTERFACE = 0
"""Interface number of the accessory's bulk IN/OUT pair (when the mode has one)."""

# bmRequestType: direction | type (vendor) | recipient (device)
REQUEST_TYPE_VENDOR_IN = 0xC0
REQUEST_TYPE_VENDOR_OUT = 0x40


class Request(enum.IntEnum):
    """AOA vendor requests (bRequest)."""

    GET_PROTOCOL = 51
    SEND_STRING = 52
    START = 53
    REGISTER_HID = 54  # AOA 2.0
    UNREGISTER_HID = 55  # AOA 2.0
    SET_HID_REPORT_DESC = 56  # AOA 2.0
    SEND_HID_EVENT = 57  # AOA 2.0
    SET_AUDIO_MODE = 58  # AOA 2.0 (audio deprecated since Android 8.0)


class StringIndex(enum.IntEnum):
    """``wIndex`` of ``SEND_STRING``."""

    MANUFACTURER = 0
    MODEL = 1
    DESCRIPTION = 2
    VERSION = 3
    URI = 4
    SERIAL = 5


class AccessoryPid(enum.IntEnum):
    """Product ids under :data:`GOOGLE_VID` once in accessory mode, by the interfaces present."""

    ACCESSORY = 0x2D00
    ACCESSORY_ADB = 0x2D01
    AUDIO = 0x2D02  # AOA 2.0
    AUDIO_ADB = 0x2D03  # AOA 2.0
    ACCESSORY_AUDIO = 0x2D04  # AOA 2.0
    ACCESSORY_AUDIO_ADB = 0x2D05  # AOA 2.0


_FIELD_TOPS = (
    ("bmRequestType", 0xFF),
    ("bRequest", 0xFF),
    ("wValue", 0xFFFF),
    ("wIndex", 0xFFFF),
    ("wLength", 0xFFFF),
)
"""A control transfer's setup fields and the largest value each holds (u8 or u16, USB 2.0 §9.3)."""


@dataclass(frozen=True, slots=True)
class ControlTransfer:
    """One USB control transfer on endpoint 0 (field names as in the USB specification).

    OUT transfers carry ``data`` (``wLength == len(data)``); IN transfers carry ``wLength``, the number
    of bytes to read."""

    bmRequestType: int
    bRequest: int
    wValue: int
    wIndex: int
    data: bytes = b""
    wLength: int = 0

    def __post_init__(self) -> None:
        """Refuse a transfer USB cannot carry, naming the field: pyusb (or the kernel) raised its own error
        for it at the moment of the transfer, or sent the fields cut to their width."""
        for name, top in _FIELD_TOPS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
                raise FieldRangeError("ControlTransfer", name, value)
        if not isinstance(self.data, (bytes, bytearray)) or (self.is_in and self.data):
            raise FieldRangeError("ControlTransfer", "data (IN transfers carry none)", self.data)
        if not self.is_in and self.wLength != len(self.data):
            raise FieldRangeError(
                "ControlTransfer", f"wLength (OUT: len(data) = {len(self.data)})", self.wLength
            )

    @property
    def is_in(self) -> bool:
        return bool(self.bmRequestType & 0x80)

    @property
    def data_or_length(self) -> bytes | int:
        """pyusb's ``data_or_wLength`` argument: bytes to write, or the count to read."""
        return self.wLength if self.is_in else self.data


@dataclass(frozen=True, slots=True)
class AccessoryIdentity:
    """The six strings an accessory announces (order = :class:`StringIndex`)."""

    manufacturer: str
    model: str
    description: str = ""
    version: str = ""
    uri: str = ""
    serial: str = ""

    def __post_init__(self) -> None:
        for f in fields(self):
            _identity_string_bytes("AccessoryIdentity", f.name, getattr(self, f.name))

    @classmethod
    def from_message(cls, message: Any) -> AccessoryIdentity:
        """The identity carried by a ``Hello`` or ``HelloReply``."""
        return cls(**{f.name: getattr(message, f.name) for f in fields(cls)})

    def strings(self) -> list[tuple[StringIndex, str]]:
        return [(StringIndex(i), getattr(self, f.name)) for i, f in enumerate(fields(self))]


def _identity_string_bytes(owner: str, name: str, value: object) -> bytes:
    """``value`` as ``SEND_STRING`` carries it — UTF-8 and its terminator — or :class:`FieldRangeError`
    naming ``owner.name``: not a string, a NUL inside (the phone keeps only what comes before it), text
    UTF-8 cannot encode (a lone surrogate), or more than :data:`ACC_STRING_SIZE` bytes with the terminator
    (the phone's gadget driver refuses the request)."""
    if not isinstance(value, str) or "\x00" in value:
        raise FieldRangeError(owner, name, value)
    try:
        data = value.encode("utf-8") + b"\x00"
    except UnicodeEncodeError:
        raise FieldRangeError(owner, name, value) from None
    if len(data) > ACC_STRING_SIZE:
        raise FieldRangeError(owner, f"{name} ({len(data)} bytes with terminator)", value)
    return data


def get_protocol() -> ControlTransfer:
    """``GET_PROTOCOL``: read the phone's AOA version (2 bytes)."""
    return ControlTransfer(REQUEST_TYPE_VENDOR_IN, int(Request.GET_PROTOCOL), 0, 0, wLength=2)


def send_string(index: StringIndex, text: str) -> ControlTransfer:
    """``SEND_STRING`` of one identity string (zero-terminated UTF-8).

    Checked as :class:`AccessoryIdentity` checks its strings (:class:`FieldRangeError` naming the string),
    and ``index`` must be one of the six: a lone surrogate raised ``UnicodeEncodeError``; a NUL inside, a
    string of 64 KiB (a ``wLength`` past u16) or an index of 6 made a transfer the phone cuts or refuses."""
    try:
        which = StringIndex(index)
    except ValueError:
        raise FieldRangeError("SEND_STRING", "wIndex", index) from None
    data = _identity_string_bytes("SEND_STRING", which.name.lower(), text)
    return ControlTransfer(REQUEST_TYPE_VENDOR_OUT, int(Request.SEND_STRING), 0, int(which), data, len(data))


def start() -> ControlTransfer:
    """``START``: switch to accessory mode (the phone re-enumerates)."""
    return ControlTransfer(REQUEST_TYPE_VENDOR_OUT, int(Request.START), 0, 0)


def start_sequence(identity: AccessoryIdentity) -> list[ControlTransfer]:
    """The whole switch, in order: GET_PROTOCOL, six SEND_STRINGs (index 0..5), START.

    A driver checks GET_PROTOCOL's answer with :func:`parse_protocol_version` before going on."""
    return [get_protocol(), *(send_string(i, s) for i, s in identity.strings()), start()]


def parse_protocol_version(data: bytes) -> int:
    """The AOA version in GET_PROTOCOL's answer. Raises :class:`ProtocolError` for an answer that is not
    2 bytes or a phone without AOA support (version 0)."""
    data = bytes(data)
    if len(data) != 2:
        raise ProtocolError(f"GET_PROTOCOL answered {len(data)} byte(s) ({data.hex()}), expected 2")
    version = int.from_bytes(data, "little")
    if version < 1:
        raise ProtocolError("the device does not support Android Open Accessory (GET_PROTOCOL = 0)")
    return version


def is_accessory_mode(vid: int, pid: int) -> bool:
    """Whether a USB device with these ids is a phone already in accessory mode."""
    return vid == GOOGLE_VID and pid in AccessoryPid._value2member_map_


@dataclass(frozen=True, slots=True)
class AccessoryInterfaces:
    """What a phone in accessory mode offers. ``accessory``: a vendor interface (number
    :data:`ACCESSORY_INTERFACE`) with one bulk IN and one bulk OUT endpoint, the data channel; ``adb``:
    the debug bridge; ``audio``: USB audio class streaming from the phone. ``min_aoa_version``: the AOA
    version that introduced this product id."""

    accessory: bool
    adb: bool
    audio: bool
    min_aoa_version: int


def accessory_interfaces(vid: int, pid: int) -> AccessoryInterfaces:
    """The interfaces of a phone in accessory mode; :class:`ProtocolError` if (vid, pid) is not one."""
    if not is_accessory_mode(vid, pid):
        raise ProtocolError(f"{vid:04x}:{pid:04x} is not an Android accessory-mode device")
    return _INTERFACES[AccessoryPid(pid)]


_A, _I = AccessoryPid, AccessoryInterfaces
_INTERFACES = {  # pid: (accessory, adb, audio, AOA version that introduced it)
    _A.ACCESSORY: _I(True, False, False, 1),
    _A.ACCESSORY_ADB: _I(True, True, False, 1),
    _A.AUDIO: _I(False, False, True, 2),
    _A.AUDIO_ADB: _I(False, True, True, 2),
    _A.ACCESSORY_AUDIO: _I(True, False, True, 2),
    _A.ACCESSORY_AUDIO_ADB: _I(True, True, True, 2),
}


__all__ = [
    "ACCESSORY_INTERFACE",
    "ACC_STRING_SIZE",
    "AccessoryIdentity",
    "AccessoryInterfaces",
    "AccessoryPid",
    "ControlTransfer",
    "GOOGLE_VID",
    "REQUEST_TYPE_VENDOR_IN",
    "REQUEST_TYPE_VENDOR_OUT",
    "Request",
    "StringIndex",
    "accessory_interfaces",
    "get_protocol",
    "is_accessory_mode",
    "parse_protocol_version",
    "send_string",
    "start",
    "start_sequence",
]

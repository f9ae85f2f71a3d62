"""Beside enumeration with the phone's own descriptors: configuration, interface and endpoint descriptors
shorter than their standard size, a wTotalLength that cuts one, a device descriptor that is not one, and
descriptors of absurd but well-formed sizes.

The board's streaming parser took a descriptor as complete at its bLength, whatever its type: an endpoint
of bLength 4 was taken with the wMaxPacketSize of the bytes before it (the interface's), an interface of
bLength 2 with the last descriptor's number, a configuration of bLength 5 with a bConfigurationValue left
from the previous read; a bLength of 0 or 1 "stopped" the parser, which read on from the next byte as if a
descriptor began there; a descriptor cut by wTotalLength was dropped without a word; and the device
descriptor's bLength and bDescriptorType were never looked at (a phone answering another descriptor was
enumerated by its bytes 7..11). Every one of them was configured, and the accessory ran on what it read.

Now: a configuration descriptor with a descriptor shorter than its type's standard size (9/9/7; 2 for any
other), or one its end cuts (unless the end is the host's own 512-byte read), fails enumeration - counted
(``enum_failures``), retried, said once (``AOA_EV_NO_ENUM``), never configured; a phone that gets well is
enumerated at the next retry. A device descriptor whose bLength is not 18 or bDescriptorType not 1 is
refused (``USB_REFUSED``, ``AOA_EV_BAD_DEVICE`` with bMaxPacketSize0 said as 0: no device descriptor said
it). Absurd sizes that parse (wTotalLength 65535, bNumInterfaces 0 or 32, a bulk wMaxPacketSize of 0 or past
64, a configuration longer than the host reads) run, or are refused, by the rules above - never a hang, a
model protocol violation, or a link up on pipes nobody said.

The firmware's USB stack on the host (``libusb-check.so``) against the MAX3421E + phone model, whose
descriptors ``usbc_descriptor`` replaces as they are (``max3421e_descriptor``)."""

from __future__ import annotations

import ctypes
import struct

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings
from test_firmware_usb_stack import EV_NO_PIPES, EV_STARTED, EV_UP, PHONE_ACCESSORY, REFUSED, RUNNING, Stack

pytestmark = pytest.mark.firmware

NORMAL, ACCESSORY = 1, 2  # the phone's modes (max3421e_phone_mode), as usbc_descriptor takes them
DEVICE, CONFIGURATION = 1, 2  # descriptor types
USB_CONFIGURED, USB_REFUSED = 8, 10  # usb_host.h
EV_NO_ENUM, EV_BAD_DEVICE = 8, 11  # aoa.h
STANDARD = {2: 9, 4: 9, 5: 7}  # USB 2.0 9.6.3/9.6.5/9.6.6: configuration, interface, endpoint
PASSES = 6000  # 1 ms passes: the switch, the accessory's three tries, the wait for the phone and the word

DEV = {
    NORMAL: bytes([18, 1, 0x00, 0x02, 0, 0, 0, 64, 0xE8, 0x04, 0x60, 0x68, 0x00, 0x04, 1, 2, 3, 1]),
    ACCESSORY: bytes([18, 1, 0x00, 0x02, 0, 0, 0, 64, 0xD1, 0x18, 0x01, 0x2D, 0x00, 0x04, 1, 2, 3, 1]),
}


def _config(parts: list[bytes], *, total: int | None = None, interfaces: int = 2) -> bytes:
    """A configuration descriptor (value 1) followed by `parts`; wTotalLength their sum unless `total`."""
    body = b"".join(parts)
    length = 9 + len(body) if total is None else total
    return struct.pack("<BBHBBBBB", 9, 2, length, interfaces, 1, 0, 0x80, 250) + body


def _interface(number: int, endpoints: int, cls: int = 0xFF, sub: int = 0xFF, proto: int = 0) -> bytes:
    return bytes([9, 4, number, 0, endpoints, cls, sub, proto, 0])


def _endpoint(address: int, mps: int = 64, attributes: int = 2) -> bytes:
    return struct.pack("<BBBBHB", 7, 5, address, attributes, mps, 0)


def _accessory_parts(in_mps: int = 64, out_mps: int = 64) -> list[bytes]:
    """The model phone's accessory configuration: interface 0 the bulk pair (IN 0x81, OUT 0x02), 1 ADB."""
    return [
        _interface(0, 2),
        _endpoint(0x81, in_mps),
        _endpoint(0x02, out_mps),
        _interface(1, 2, 0xFF, 0x42, 0x01),
        _endpoint(0x83),
        _endpoint(0x03),
    ]


def _normal_parts() -> list[bytes]:
    """The model phone's normal configuration: MTP (bulk pair and an interrupt IN), then ADB."""
    return [
        _interface(0, 3, 0x06, 0x01, 0x01),
        _endpoint(0x81),
        _endpoint(0x01),
        _endpoint(0x82, 28, attributes=3),
        _interface(1, 2, 0xFF, 0x42, 0x01),
        _endpoint(0x83),
        _endpoint(0x02),
    ]


PARTS = {NORMAL: _normal_parts, ACCESSORY: _accessory_parts}


class DescriptorStack(Stack):
    """The stack against a phone whose descriptors the test gives."""

    def __init__(self) -> None:
        super().__init__()
        fn = self.lib.usbc_descriptor
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_uint8), ctypes.c_size_t]
        self.lib.usbc_refused.restype, self.lib.usbc_refused.argtypes = ctypes.c_uint16, []

    def descriptor(self, mode: int, kind: int, data: bytes) -> None:
        buf = (ctypes.c_uint8 * max(1, len(data))).from_buffer_copy(data or b"\0")
        assert self.lib.usbc_descriptor(mode, kind, buf, len(data)) == 0, (mode, kind, len(data))

    def run_watching(self, passes: int) -> set[tuple[int, int]]:
        """Run `passes` passes: every (phone mode, host state) seen between them."""
        seen = set()
        for _ in range(passes):
            self.step()
            seen.add((self.lib.usbc_phone_mode(), self.lib.usbc_host_state()))
        return seen


def _bytes_flow(stack: Stack) -> bool:
    payload = bytes(range(256)) * 2
    stack.phone_write(payload)
    stack.board_write(payload[::-1])
    board, phone = stack.pump(200)
    return board == payload and phone == payload[::-1]


def _refused_as_unusable_configuration(s: DescriptorStack, mode: int) -> None:
    """The phone in `mode` fails enumeration: never configured there, counted, said once; then, its good
    descriptor back, the next retry enumerates it and the accessory's bytes flow."""
    seen = s.run_watching(PASSES)
    assert (mode, USB_CONFIGURED) not in seen, "configured on a malformed configuration descriptor"
    events = s.events()
    assert EV_UP not in [e for e, _ in events], events
    if mode == NORMAL:
        assert EV_STARTED not in [e for e, _ in events], events  # never switched by a device it cannot read
        assert s.phone_strings() == [""] * 6
    assert [e for e, _ in events if e != EV_STARTED] == [EV_NO_ENUM], events  # said once
    assert s.stats()["enum_failures"] >= 3, s.stats()
    assert s.last_error() == "", s.last_error()
    s.descriptor(mode, CONFIGURATION, _config(PARTS[mode]()))
    assert s.run_until(RUNNING, PASSES) > 0, (s.events(), s.stats(), s.last_error())
    assert _bytes_flow(s)
    assert s.last_error() == ""


# ---------------------------------------------------------------------- shorter than the standard size
@settings(max_examples=40, deadline=None)
@given(
    mode=st.sampled_from([NORMAL, ACCESSORY]),
    data=st.data(),
)
@example(mode=ACCESSORY, data=None)  # an endpoint of bLength 4: its wMaxPacketSize from the interface's bytes
def test_a_descriptor_shorter_than_its_standard_size_fails_enumeration_never_parsed_from_stale_bytes(
    mode: int, data: st.DataObject | None
) -> None:
    config = [bytes(_config([]))] + PARTS[mode]()  # the configuration descriptor itself is index 0
    if data is None:
        which, length = 2, 4
    else:
        which = data.draw(st.integers(0, len(config) - 1), label="descriptor")
        length = data.draw(st.integers(0, STANDARD[config[which][1]] - 1), label="bLength")
    short = (
        bytes([length]) + config[which][1 : max(length, 2)]
    )  # its own bytes up to bLength (at least its type)
    parts = config[1:]
    if which == 0:
        head = short
    else:
        head = config[0]
        parts[which - 1] = short
    body = b"".join(parts)
    total = len(head) + len(body)
    head = head[:2] + struct.pack("<H", total)[: max(0, len(head) - 2)] + head[4:]
    s = DescriptorStack()
    try:
        s.descriptor(mode, CONFIGURATION, head + body)
        _refused_as_unusable_configuration(s, mode)
    finally:
        s.close()


# ---------------------------------------------------------------------- a wTotalLength that cuts one
@settings(max_examples=40, deadline=None)
@given(mode=st.sampled_from([NORMAL, ACCESSORY]), data=st.data())
@example(mode=ACCESSORY, data=None)  # the ADB interface's last endpoint cut: the accessory's pair is whole
def test_a_wTotalLength_that_cuts_a_descriptor_fails_enumeration(
    mode: int, data: st.DataObject | None
) -> None:
    full = _config(PARTS[mode]())
    starts, at = [], 0
    while at < len(full):
        starts.append(at)
        at += full[at]
    if data is None:
        cut = len(full) - 3
    else:
        cut = data.draw(
            st.integers(10, len(full) - 1).filter(lambda k: k not in starts), label="wTotalLength"
        )
    cut_config = full[:2] + struct.pack("<H", cut) + full[4:cut]
    s = DescriptorStack()
    try:
        s.descriptor(mode, CONFIGURATION, cut_config)
        _refused_as_unusable_configuration(s, mode)
    finally:
        s.close()


@pytest.mark.parametrize("length", [0, 1, 255])
@pytest.mark.parametrize("which", [1, 2, 3])  # the bulk pair's interface, its IN and its OUT endpoint
def test_a_bLength_of_0_1_or_255_fails_enumeration(which: int, length: int) -> None:
    """0 and 1 are no descriptor at all; 255 runs past the configuration's end."""
    parts = _accessory_parts()
    parts[which - 1] = bytes([length]) + parts[which - 1][1:]
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, _config(parts))
        _refused_as_unusable_configuration(s, ACCESSORY)
    finally:
        s.close()


# ---------------------------------------------------------------------- a device descriptor that is not one
@settings(max_examples=30, deadline=None)
@given(
    mode=st.sampled_from([NORMAL, ACCESSORY]),
    header=st.one_of(
        st.tuples(st.just(18), st.integers(0, 255).filter(lambda t: t != DEVICE)),  # another type
        st.tuples(st.integers(0, 255).filter(lambda n: n != 18), st.just(DEVICE)),  # another length
    ),
)
@example(mode=NORMAL, header=(18, CONFIGURATION))
@example(mode=ACCESSORY, header=(18, 0))
@example(mode=NORMAL, header=(9, DEVICE))
def test_a_device_descriptor_of_another_type_or_length_is_refused_once_said(
    mode: int, header: tuple[int, int]
) -> None:
    s = DescriptorStack()
    try:
        s.descriptor(mode, DEVICE, bytes(header) + DEV[mode][2:])
        seen = s.run_watching(PASSES)
        assert (mode, USB_CONFIGURED) not in seen, "configured by a descriptor that is not a device's"
        assert s.lib.usbc_host_state() == USB_REFUSED, (s.lib.usbc_host_state(), s.stats())
        assert s.lib.usbc_refused() == 1
        events = s.events()
        assert [e for e, _ in events if e != EV_STARTED] == [EV_BAD_DEVICE], events
        assert events[-1] == (EV_BAD_DEVICE, 0)  # no device descriptor said a bMaxPacketSize0
        assert s.last_error() == ""
        # unplugged; the same phone with its device descriptor mended plugged in: it runs
        s.fault("detach")
        s.step(5)
        s.descriptor(mode, DEVICE, DEV[mode])
        s.fault("attach")
        assert s.run_until(RUNNING, PASSES) > 0, (s.events(), s.stats())
        assert _bytes_flow(s)
        assert s.last_error() == ""
    finally:
        s.close()


@settings(max_examples=20, deadline=None)
@given(kind=st.integers(0, 255).filter(lambda t: t != CONFIGURATION))
def test_a_configuration_descriptor_of_another_type_fails_enumeration(kind: int) -> None:
    config = _config(_accessory_parts())
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, config[:1] + bytes([kind]) + config[2:])
        _refused_as_unusable_configuration(s, ACCESSORY)
    finally:
        s.close()


# ---------------------------------------------------------------------- absurd but well-formed sizes
def _runs(s: DescriptorStack, in_packet: int = 64, out_packet: int = 64) -> None:
    assert s.run_until(RUNNING, PASSES) > 0, (s.events(), s.stats(), s.last_error())
    dev = s.device()
    assert (dev["in_packet"], dev["out_packet"]) == (in_packet, out_packet), dev
    assert _bytes_flow(s)
    assert s.stats()["enum_failures"] == 0
    assert s.last_error() == ""


@pytest.mark.parametrize(
    "config",
    [
        pytest.param(_config(_accessory_parts(), total=65535), id="wTotalLength-65535-answer-shorter"),
        pytest.param(_config(_accessory_parts(), interfaces=0), id="bNumInterfaces-0"),
        pytest.param(_config(_accessory_parts(), interfaces=32), id="bNumInterfaces-32"),
        # a configuration longer than the host's 512-byte read: the descriptor its read ends in is the
        # host's cut, not the device's
        pytest.param(
            _config([*_accessory_parts(), *[bytes([100, 0x24]) + bytes(98)] * 6]), id="longer-than-512-read"
        ),
        # a longer bLength than the standard's (USB allows it): the standard fields, the rest skipped
        pytest.param(
            _config([bytes([12]) + _interface(0, 2)[1:] + bytes(3), *_accessory_parts()[1:]]),
            id="interface-bLength-12",
        ),
    ],
)
def test_absurd_but_well_formed_configurations_run(config: bytes) -> None:
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, config)
        _runs(s)
    finally:
        s.close()


@pytest.mark.parametrize("mps", [65, 100, 255, 512, 1023])
def test_a_bulk_wMaxPacketSize_past_64_runs_at_the_full_speed_packet(mps: int) -> None:
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, _config(_accessory_parts(in_mps=mps, out_mps=mps)))
        _runs(s)
    finally:
        s.close()


@pytest.mark.parametrize("which", ["in", "out"])
def test_a_bulk_wMaxPacketSize_of_0_is_no_pipe_refused_once_said(which: str) -> None:
    s = DescriptorStack()
    try:
        parts = _accessory_parts(in_mps=0 if which == "in" else 64, out_mps=0 if which == "out" else 64)
        s.descriptor(ACCESSORY, CONFIGURATION, _config(parts))
        s.step(PASSES)
        assert s.state == REFUSED
        assert [e for e, _ in s.events()] == [EV_STARTED, EV_NO_PIPES], s.events()
        assert s.lib.usbc_phone_mode() == PHONE_ACCESSORY
        assert s.last_error() == ""
    finally:
        s.close()


@pytest.mark.parametrize("total", [0, 1, 8])
def test_a_wTotalLength_below_9_fails_enumeration(total: int) -> None:
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, _config(_accessory_parts(), total=total))
        _refused_as_unusable_configuration(s, ACCESSORY)
    finally:
        s.close()


# ---------------------------------------------------------------------- an alternate setting's endpoints
def _alternate_interface(number: int, alternate: int, endpoints: int) -> bytes:
    return bytes([9, 4, number, alternate, endpoints, 0xFF, 0xFF, 0, 0])


@pytest.mark.parametrize("alternate", [1, 2, 255])
def test_a_bulk_pair_only_in_an_alternate_setting_is_no_pipe_refused_once_said(alternate: int) -> None:
    """Interface 0's default setting has no endpoints; its alternate `alternate` has the bulk pair. The board
    selects no alternate setting (SET_CONFIGURATION makes 0 the active one), so those endpoints are not
    active: it took them for the accessory's pipes, every transaction on them timed out, eight errors
    re-enumerated it, and round it went - "connected" / "disconnected" for as long as it stayed plugged in.
    Now it is an accessory without a bulk pair: refused, said once."""
    parts = [
        _alternate_interface(0, 0, 0),
        _alternate_interface(0, alternate, 2),
        _endpoint(0x81),
        _endpoint(0x02),
        *_accessory_parts()[3:],  # ADB
    ]
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, _config(parts))
        s.step(PASSES)
        assert s.state == REFUSED, (s.state, s.events(), s.stats())
        assert [e for e, _ in s.events()] == [EV_STARTED, EV_NO_PIPES], s.events()
        assert s.last_error() == "", s.last_error()  # no transaction on an endpoint that is not active
    finally:
        s.close()


def test_a_bulk_pair_in_the_default_setting_runs_beside_an_alternate_one() -> None:
    parts = [
        _alternate_interface(0, 0, 2),
        _endpoint(0x81),
        _endpoint(0x02),
        _alternate_interface(0, 1, 2),
        _endpoint(0x84),
        _endpoint(0x05),
        *_accessory_parts()[3:],
    ]
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, _config(parts))
        _runs(s)
        assert (s.device()["bulk_in"], s.device()["bulk_out"]) == (1, 2)
    finally:
        s.close()


# ---------------------------------------------------------------------- unplugged at a drawn moment
MALFORMED = {
    "endpoint-bLength-4": _config([_accessory_parts()[0], bytes([4, 5, 0x81, 2]), *_accessory_parts()[2:]]),
    "interface-bLength-0": _config([bytes([0]) + _interface(0, 2)[1:], *_accessory_parts()[1:]]),
    "cut-by-wTotalLength": (lambda full: full[:2] + struct.pack("<H", 30) + full[4:30])(
        _config(_accessory_parts())
    ),
    "alternate-setting-pair": _config(
        [_alternate_interface(0, 0, 0), _alternate_interface(0, 1, 2), *_accessory_parts()[1:]]
    ),
}


@settings(max_examples=40, deadline=None)
@given(
    kind=st.sampled_from(sorted(MALFORMED)),
    at_us=st.integers(0, 9_000_000),  # the switch, the accessory's tries, the wait, the word, the retries
    out_us=st.integers(0, 400_000),
)
def test_a_phone_unplugged_at_any_moment_of_its_refusal_and_mended_runs(
    kind: str, at_us: int, out_us: int
) -> None:
    """The accessory's configuration malformed; the phone unplugged at a drawn moment of its switch, its
    failed enumerations, the retries or its refusal, and plugged back mended: it runs, the accessory's link
    up exactly once (never on the malformed one), no protocol violation."""
    s = DescriptorStack()
    try:
        s.descriptor(ACCESSORY, CONFIGURATION, MALFORMED[kind])
        seen = s.run_watching(at_us // 1000)
        s.lib.usbc_step(at_us % 1000)
        s.fault("detach")
        seen |= s.run_watching(out_us // 1000)
        if kind != "alternate-setting-pair":  # that one configures, then is refused for want of a pair
            assert (ACCESSORY, USB_CONFIGURED) not in seen, "configured on a malformed descriptor"
        s.descriptor(ACCESSORY, CONFIGURATION, _config(_accessory_parts()))
        s.fault("attach")
        assert s.run_until(RUNNING, PASSES) > 0, (s.events(), s.stats(), s.last_error())
        assert [e for e, _ in s.events()].count(EV_UP) == 1, s.events()
        assert s.events()[-1][0] == EV_UP
        assert _bytes_flow(s)
        assert s.last_error() == "", s.last_error()
    finally:
        s.close()

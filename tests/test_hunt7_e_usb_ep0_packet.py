"""Beside enumeration with the phone's own 64-byte endpoint 0: a device descriptor whose bMaxPacketSize0
full speed does not allow.

USB 2.0 (9.6.1) allows only 8, 16, 32 and 64 for a full-speed device's endpoint 0. The board took any
value from 8 to 64 (and quietly made anything else 8): a device saying 40 was enumerated and configured
with control transfers split at a boundary it does not keep. Now such a device is refused: left
unconfigured (host state ``USB_REFUSED``), no bus-reset loop, counted (``usb_stats.refused``) and said
once in the log (``AOA_EV_BAD_DEVICE``, an error naming the value); a phone plugged in after it with a
lawful size runs. Every lawful size enumerates, and the accessory's bytes flow.

The firmware's USB stack on the host (``libusb-check.so``) against the MAX3421E + phone model, whose
``ep0_packet`` fault sets the phone's bMaxPacketSize0 and the size of its endpoint-0 packets."""

from __future__ import annotations

import ctypes

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings
from test_firmware_usb_stack import RUNNING, Stack

pytestmark = pytest.mark.firmware

LAWFUL = (8, 16, 32, 64)
USB_REFUSED = 10  # usb_host.h
EV_BAD_DEVICE = 11  # aoa.h
PASSES = 2000  # 1 ms passes: two enumerations, the handshake and the switch fit well within


def _fresh_stack() -> Stack:
    """A stack started afresh, the phone plugged in (one per Hypothesis example: a fixture is not)."""
    s = Stack()
    s.lib.usbc_refused.restype, s.lib.usbc_refused.argtypes = ctypes.c_uint16, []
    return s


@pytest.fixture
def stack():
    s = _fresh_stack()
    yield s
    s.close()


@settings(max_examples=60, deadline=None)
@given(size=st.integers(0, 255).filter(lambda v: v not in LAWFUL))
@example(size=40)  # inside 8..64: was taken
@example(size=9)
@example(size=0)  # below 8: was made 8 without a word
def test_a_bMaxPacketSize0_full_speed_does_not_allow_is_refused_once_counted_and_said(size):
    stack = _fresh_stack()
    try:
        _refused_then_a_lawful_phone_runs(stack, size)
    finally:
        stack.close()


def _refused_then_a_lawful_phone_runs(stack: Stack, size: int) -> None:
    stack.fault("ep0_packet", size)
    stack.step(3000)  # 3 s: would have been configured, or retried with bus resets, long before
    assert stack.lib.usbc_host_state() == USB_REFUSED, (size, stack.stats())
    assert stack.state != RUNNING
    stats = stack.stats()
    assert stats["attaches"] == 1 and stats["enum_failures"] == 0, stats  # no reset loop
    assert stack.lib.usbc_refused() == 1
    # packets of 1..7 bytes end the 8-byte read short, before byte 7 says the size: said as 0
    said = 0 if 1 <= size < 8 else size
    assert stack.events() == [(EV_BAD_DEVICE, said)]  # said once
    text = stack.event_text(EV_BAD_DEVICE, said)
    assert "refused" in text and "bMaxPacketSize0" in text and text.endswith(f"0x{said:x}"), text
    assert stack.last_error() == ""
    # unplugged, and a phone with a lawful endpoint 0 plugged in: it runs
    stack.fault("detach")
    stack.step(5)
    stack.fault("ep0_packet", 64)
    stack.fault("attach")
    assert stack.run_until(RUNNING, PASSES) > 0
    assert stack.lib.usbc_refused() == 1
    assert stack.last_error() == ""


@pytest.mark.parametrize("size", LAWFUL)
def test_every_lawful_bMaxPacketSize0_enumerates_and_the_bytes_flow(stack, size):
    stack.fault("ep0_packet", size)
    assert stack.run_until(RUNNING, PASSES) > 0, stack.stats()
    assert stack.device()["max_packet0"] == size
    assert stack.phone_strings()[5] == "LAB-01"  # SEND_STRING's OUT data in packets of `size`
    assert stack.lib.usbc_refused() == 0
    assert stack.last_error() == ""

"""Beside ``test_hunt7_e_usb_replug_enumeration.py`` (a replug at a drawn pass of the attach, reset and
enumeration): a phone pulled out and plugged back in the microseconds between the chip ending its bus reset
and the firmware's next look at it, while the main loop is busy elsewhere.

The firmware cleared the connect event it found latched at the reset's end as the reset's own, sampled the
bus (attached again: J) and enumerated a device that had never been reset - it answers nothing until a bus
reset - so ~500 transaction errors until the control transfer's 0.5 s deadline, an enumeration failure
counted, and a retry. A connect event latched when the reset ends is now a replug (once per attach, as one
in the reset recovery is): the phone gets its own debounce and bus reset.

The firmware's USB stack on the host (``libusb-check.so``) against the MAX3421E + phone model;
``usbc_advance`` moves the simulated clock with no pass of the stack (the board busy elsewhere)."""

from __future__ import annotations

import ctypes

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings
from test_firmware_usb_stack import RUNNING, Stack

pytestmark = pytest.mark.firmware

USB_RESETTING = 5  # usb_host.h
BUS_RESET_US = 50_000  # the chip's bus reset
FRESH_ATTACH_PASSES = 1200  # debounce, reset, recovery, enumeration, the AOA switch and its own: < 1.2 s


def _advance(stack: Stack, us: int) -> None:
    stack.lib.usbc_advance.argtypes = [ctypes.c_uint32]
    stack.lib.usbc_advance.restype = None
    stack.lib.usbc_advance(us)


@settings(max_examples=40, deadline=None)
@given(after_end_us=st.integers(100, 3_000), out_us=st.integers(0, 2_000), later_us=st.integers(0, 500))
@example(after_end_us=100, out_us=0, later_us=0)  # out and back in at once, just after the reset's end
def test_a_replug_just_after_the_reset_ends_gets_its_own_reset(after_end_us, out_us, later_us):
    stack = Stack()
    try:
        assert stack.run_until(RUNNING) > 0
        stack.fault("detach")
        stack.step(5)
        stack.fault("attach")  # a fresh attach: debounce, then the bus reset
        for _ in range(400):
            if stack.lib.usbc_host_state() == USB_RESETTING:
                break
            stack.step()
        assert stack.lib.usbc_host_state() == USB_RESETTING
        stack.step(BUS_RESET_US // 1000 - 1)  # passes during the reset (it ends within the next ms)
        assert stack.lib.usbc_host_state() == USB_RESETTING
        _advance(stack, 1000 + after_end_us)  # the reset ended meanwhile; the board has not looked yet
        stack.fault("detach")
        _advance(stack, out_us)
        stack.fault("attach")
        _advance(stack, later_us)
        failures = stack.stats()["enum_failures"]
        passes = stack.run_until(RUNNING, FRESH_ATTACH_PASSES)
        assert stack.last_error() == "", (after_end_us, out_us, stack.stats())
        assert passes > 0, stack.stats()
        assert stack.stats()["enum_failures"] == failures, stack.stats()
    finally:
        stack.close()


@settings(max_examples=15, deadline=None)
@given(late_us=st.integers(1, 2_500))
def test_a_chip_that_says_its_own_reset_end_before_the_look_is_not_reset_for_ever(late_us):
    """The other side of the fix: a chip raising CONDETIRQ a moment after each bus reset ends, the phone
    never having moved, is found latched at the firmware's look when the moment is shorter than a pass:
    taken for a replug once per attach (one more debounce and reset), then for the reset's own."""
    stack = Stack()
    try:
        stack.fault("condet_after_reset", late_us)
        assert stack.run_until(RUNNING, 2 * FRESH_ATTACH_PASSES) > 0, stack.stats()
        stats = stack.stats()
        # the phone, its switch into accessory mode (two attaches), each taken once more at most
        assert stats["attaches"] <= 4 and stats["enum_failures"] == 0, stats
        assert stack.last_error() == ""
    finally:
        stack.close()

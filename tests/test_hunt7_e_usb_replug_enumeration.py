"""Beside the replug tests of ``test_firmware_usb_stack.py`` (a replug between two passes while the board
refuses or runs the phone): a phone pulled out and plugged back at a drawn moment of its attach, bus reset,
reset recovery, enumeration and AOA switch.

A phone plugged back inside the 20 ms reset recovery was taken for the reset's own end: the board went on
enumerating a device that had never been reset (it answers nothing until a bus reset), ~500 transfer
errors until the control transfer's 0.5 s deadline, then a retry - the link back ~0.9 s late. Whatever the
moment, a replug must start over with a bus reset: the model's ``last_error`` (a transaction to a device
that is not in its default state) stays empty, and the accessory is up again within one fresh attach's
time.

The firmware's USB stack on the host (``libusb-check.so``) against the MAX3421E + phone model."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings
from test_firmware_usb_stack import RUNNING, Stack

pytestmark = pytest.mark.firmware

# a fresh attach: debounce 200 ms, reset 50 ms, recovery 20 ms, enumeration, handshake, the switch, again
FRESH_ATTACH_PASSES = 1200  # 1 ms passes: a replug is up again within this, no 0.5 s deadline ridden
ATTACH_TO_RECOVERY_US = 250_000 + 5_000  # inside the reset recovery after an attach (200 + 50 ms, + 5)


def _advance(stack: Stack, us: int) -> None:
    """Main-loop passes of 1 ms over `us` microseconds (the last one shorter)."""
    while us > 0:
        stack.lib.usbc_step(min(us, 1000))
        us -= 1000


@settings(max_examples=100, deadline=None)
@given(at_us=st.integers(0, 700_000), out_us=st.one_of(st.just(0), st.integers(1, 30_000)))
@example(at_us=ATTACH_TO_RECOVERY_US, out_us=0)  # out and back in between two looks, in the recovery
@example(at_us=ATTACH_TO_RECOVERY_US, out_us=300)  # a glitch shorter than a pass, in the recovery
def test_a_replug_at_any_moment_of_enumeration_starts_over_with_a_bus_reset(at_us, out_us):
    stack = Stack()  # afresh for every example
    try:
        _replug_at(stack, at_us, out_us)
    finally:
        stack.close()


def _replug_at(stack: Stack, at_us: int, out_us: int) -> None:
    assert stack.run_until(RUNNING) > 0
    stack.fault("detach")
    stack.step(5)
    stack.fault("attach")  # a phone plugged in: attach, reset, enumeration, handshake, switch, again
    _advance(stack, at_us)
    stack.fault("detach")
    _advance(stack, out_us)
    stack.fault("attach")
    passes = stack.run_until(RUNNING, FRESH_ATTACH_PASSES)
    assert stack.last_error() == "", (at_us, out_us, stack.stats())
    assert passes > 0, (at_us, out_us, stack.stats())
    assert stack.stats()["enum_failures"] == 0, stack.stats()


@pytest.mark.parametrize("late_us", [1_500, 5_000, 19_000])
def test_a_chip_that_says_its_own_reset_end_late_is_not_reset_for_ever(late_us):
    """The other side of the fix: a connect event in the reset recovery is taken for a replug once per
    attach, so a chip raising CONDETIRQ after each reset ends (after the driver cleared it, the phone never
    having moved) costs one extra debounce and reset, not a reset loop."""
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

"""Beside ``test_firmware_beside_usb_give_up.py`` (an endpoint that STALLs again after every clear): a phone
that halts a bulk endpoint and then NAKs the CLEAR_FEATURE(ENDPOINT_HALT) for ever.

The clear timed out at the control transfer's 0.5 s deadline, the board enumerated the phone again (which
resets its endpoints), found it halted again, sent the clear again - a round every ~0.6 s for as long as the
phone stayed plugged in, the link dead and nothing said. Now the failed clears count across those
re-enumerations (not across replugs) and, after ``AOA_CLEAR_TRIES``, the accessory is refused until it is
unplugged, with the ``Log`` naming the endpoint, as an endpoint that keeps stalling is.

The firmware's USB stack on the host (``libusb-check.so``) against the MAX3421E + phone model."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_firmware_usb_stack import IDLE, REFUSED, RUNNING, Stack

pytestmark = pytest.mark.firmware

EV_DOWN, EV_STALLED = 2, 10
AOA_CLEAR_TRIES = 3
ROUND_PASSES = 700  # one clear to its 0.5 s deadline, and a re-enumeration (1 ms passes)


def _halted_for_ever(stack: Stack, ep: int, passes: int) -> None:
    """The phone halts `ep` again before every pass and never completes a clear."""
    stack.fault("clear_halt_nak", 1)
    for _ in range(passes):
        stack.fault("stall", ep)
        stack.step()


@settings(max_examples=6, deadline=None)
@given(direction=st.sampled_from(["in", "out"]), extra_rounds=st.integers(0, 6))
def test_a_clear_feature_nakked_for_ever_is_bounded_and_said(direction, extra_rounds):
    stack = Stack()
    try:
        assert stack.run_until(RUNNING) > 0
        dev = stack.device()
        ep = dev["bulk_in"] if direction == "in" else dev["bulk_out"]
        ep_addr = 0x80 | ep if direction == "in" else ep
        stack.board_write(b"queued for the phone" * 5)
        if direction == "in":
            stack.phone_write(b"from the app")
        before = len(stack.events())
        enum_failures = stack.stats()["enum_failures"]
        _halted_for_ever(stack, ep, (AOA_CLEAR_TRIES + 1 + extra_rounds) * ROUND_PASSES)
        attaches_then = stack.stats()["attaches"]
        _halted_for_ever(stack, ep, 2 * ROUND_PASSES)  # nothing more happens: no round without end
        assert stack.state == REFUSED, (stack.events()[before:], stack.stats())
        assert stack.events()[before:][-2:] == [(EV_DOWN, 0), (EV_STALLED, ep_addr)], stack.events()[before:]
        downs = [e for e, _ in stack.events()[before:] if e == EV_DOWN]
        assert len(downs) == AOA_CLEAR_TRIES, stack.events()[before:]
        assert stack.stats()["attaches"] == attaches_then
        assert stack.stats()["enum_failures"] == enum_failures
        assert stack.event_text(EV_STALLED, ep_addr) == (
            f"USB accessory refused: its bulk endpoint keeps stalling, 0x{ep_addr:x}"
        )
        # unplugged and plugged back, a phone that takes its clears gets the stream again
        stack.fault("clear_halt_nak", 0)
        stack.fault("detach")
        assert stack.run_until(IDLE, 50) > 0
        stack.fault("attach")
        assert stack.run_until(RUNNING) > 0
        stack.board_write(b"after the replug")
        _, phone = stack.pump(50)
        assert phone.endswith(b"after the replug")
        assert stack.last_error() == ""
    finally:
        stack.close()


def test_a_clear_nakked_once_then_taken_is_not_a_refusal():
    """The count is of clears that failed since the device was plugged in, ended by one that succeeds: a
    phone that NAKs one clear to its deadline, then takes the next, keeps its link."""
    stack = Stack()
    try:
        assert stack.run_until(RUNNING) > 0
        ep = stack.device()["bulk_out"]
        stack.board_write(b"first" * 20)
        _halted_for_ever(stack, ep, ROUND_PASSES)  # one clear fails: re-enumerated
        stack.fault("clear_halt_nak", 0)
        for _ in range(AOA_CLEAR_TRIES + 2):  # then halts it now and then, each clear taken
            assert stack.run_until(RUNNING) > 0
            stack.fault("stall", ep)
            stack.board_write(b"more")
            stack.step(5)
        assert stack.run_until(RUNNING) > 0
        stack.board_write(b"the end")
        _, phone = stack.pump(50)
        assert phone.endswith(b"the end")
        assert stack.last_error() == ""
    finally:
        stack.close()

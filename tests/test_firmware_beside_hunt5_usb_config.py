"""Beside the USB host stack's enumeration: a configuration descriptor that parses but names a
configuration no host can select.

A phone (normal or accessory mode) whose configuration descriptor says ``bConfigurationValue`` 0 (the
model's ``config_value`` fault): the board sent SET_CONFIGURATION(0) - which USB defines as "unconfigure" -
and took the device for configured. As an accessory it opened the bulk pair (``Log`` "USB accessory
connected"), every bulk transaction timed out (the phone, in its address state, does not answer its
endpoints), eight errors re-enumerated it, and round it went: "connected" / "disconnected" about ten times a
second for as long as it stayed plugged in, a link shown up that never carried a byte. Now such a
configuration fails enumeration like any unusable descriptor: three tries, one ERROR ``Log`` (``HANDSHAKE``,
"USB device not enumerated ..."), retried every second; a phone that gets well is enumerated at the next try.

The stack on the host through ctypes (``test_firmware_usb_stack.Stack``) against the MAX3421E + phone model
(its ``last_error``, a USB protocol violation by the board, must stay empty), and the whole firmware under
simavr for what the phone's app reads."""

from __future__ import annotations

import time

import hypothesis.strategies as st
import pytest
from conformance.host import SerialHost
from hypothesis import given, settings
from test_firmware_usb_link import PHONE_ACCESSORY, board, usb, wait_mode
from test_firmware_usb_stack import EV_DOWN, EV_STARTED, EV_UP, IDLE, PASS_US, RUNNING, Stack

from firmware_sim.board.codes import LogCode
from protocol.messages import BoardState, Log, Severity

pytestmark = pytest.mark.firmware

EV_NO_ENUM = 8  # aoa.h
USB_CONFIGURED = 8  # usb_host.h
HR_SUCCESS = 0x0


def _bytes_flow(stack: Stack) -> bool:
    payload = bytes(range(200))
    stack.phone_write(payload)
    stack.board_write(payload[::-1])
    board, phone = stack.pump(100)
    return board == payload and phone == payload[::-1]


@settings(max_examples=12, deadline=None)
@given(
    accessory_only=st.booleans(),  # the phone's normal mode gives a good descriptor, only the accessory not
    away_s=st.floats(1.0, 4.0),
)
def test_a_configuration_value_of_zero_fails_enumeration_once_said_never_a_flapping_link(
    accessory_only: bool, away_s: float
) -> None:
    s = Stack()
    try:
        if accessory_only:
            assert s.run_until(RUNNING) > 0  # switched and running with a good descriptor first
            s.fault("detach")
            s.step(5)
            s.fault("config_value", 0)
            s.fault("attach")  # back as a normal phone, then START: its accessory mode is the bad one
        else:
            s.fault("config_value", 0)
        before = len(s.events())
        s.step(int(away_s * 1e6) // PASS_US + 3000)
        events = s.events()[before:]
        assert s.last_error() == "", s.last_error()  # no SET_CONFIGURATION(0), no unconfigured endpoint
        assert EV_UP not in [e for e, _ in events], events  # never shown as a live accessory
        assert [e for e, _ in events if e != EV_STARTED] == [EV_NO_ENUM], events  # said once (START aside)
        assert events[-1] == (EV_NO_ENUM, HR_SUCCESS)
        assert s.lib.usbc_host_state() != USB_CONFIGURED
        assert s.state == IDLE  # not refused: the retries go on
        s.fault("config_value", 1)  # the phone gets well: the next retry (every second) enumerates it
        assert s.run_until(RUNNING, 5000) > 0, (s.events(), s.last_error())
        assert s.events()[-1][0] == EV_UP
        assert _bytes_flow(s)
        assert s.last_error() == ""
    finally:
        s.close()


@pytest.mark.parametrize("value", [2, 7, 255])
def test_any_nonzero_configuration_value_is_selected_and_carries_bytes(value: int) -> None:
    s = Stack()
    try:
        s.fault("config_value", value)
        assert s.run_until(RUNNING) > 0, (s.events(), s.last_error())
        assert _bytes_flow(s)
        assert EV_DOWN not in [e for e, _ in s.events()]
        assert s.last_error() == ""
    finally:
        s.close()


def test_the_whole_board_says_it_once_and_never_shows_a_link_up() -> None:
    """The firmware under simavr, the phone's accessory mode giving bConfigurationValue 0 for 3 s of board
    time, then a good one: the app reads one ERROR Log (HANDSHAKE) saying why there was no link, and a single
    "USB accessory connected" - the one of the phone that got well, not one per flap."""
    with board() as b:
        usb(b, "config_value", "0")
        usb(b, "detach")
        t0 = usb(b, "attach")
        end = time.monotonic() + 30.0
        while usb(b, "config_value", "0") - t0 < 3.0:  # START, the accessory's three tries and more
            assert time.monotonic() < end, "the board's clock did not get through 3 s"
            time.sleep(0.25)
        host = SerialHost(b.port)
        try:
            usb(b, "config_value", "1")  # the next retry (every second) enumerates it
            wait_mode(b, PHONE_ACCESSORY)
            logs: list[Log] = []
            stop = time.monotonic() + 3.0
            while time.monotonic() < stop:
                logs += [m for m in host.poll(0.1) if isinstance(m, Log)]
            texts = [log.text for log in logs]
            refusals = [log for log in logs if log.code == LogCode.HANDSHAKE]
            assert [log.text for log in refusals] == [
                "USB device not enumerated, retrying every second; last HRSL 0x0"
            ], texts
            assert refusals[0].severity == Severity.ERROR
            assert sum(t.startswith("USB accessory connected") for t in texts) == 1, texts
            assert host.handshake().state == BoardState.DISARMED
        finally:
            host.close()
        assert b.command("usbstate")[7] == "-"  # the model's last_error: no protocol violation

"""Beside the USB host stack's tested path: failures that repeat without end must end in one honest,
bounded report, never a silent loop.

* a phone that takes AOA START, drops off the bus and comes back in its *normal* mode each time (the
  model's ``never_switch 2``): every return is a new device to the host, and the handshake's try count
  was reset at each one, so the board sent START (and a ``Log``) every ~0.3 s for ever; now the phone's
  failed switches count across its own re-enumerations and it is refused after ``AOA_HANDSHAKE_TRIES``;
* a phone whose bulk endpoint STALLs again after every CLEAR_FEATURE: the board cleared it for ever, the
  link dead and nothing said; now, after ``AOA_PIPE_ERRORS`` STALLs with nothing moving between, the
  accessory is refused until unplugged, with a ``Log`` naming the endpoint;
* a device whose enumeration keeps failing, and a MAX3421E whose oscillator never starts: the host stack
  retried every second and the board never said why there was no link; now one ERROR ``Log`` (code
  ``HANDSHAKE``) says so, once per device plugged in, and the retries go on.

The stack on the host through ctypes (``test_firmware_usb_stack.Stack``), and the real firmware under
simavr for the ``Log`` the host reads."""

from __future__ import annotations

import time

import hypothesis.strategies as st
import pytest
from conformance.host import SerialHost
from hypothesis import given, settings
from test_firmware_usb_link import PHONE_ACCESSORY, board, usb, wait_mode
from test_firmware_usb_stack import (
    AOA_HANDSHAKE_TRIES,
    AOA_REENUM_US,
    EV_STARTED,
    EV_UP,
    IDLE,
    PASS_US,
    PHONE_NORMAL,
    REFUSED,
    RUNNING,
    Stack,
)

from firmware_sim.board.codes import LogCode
from protocol.messages import BoardState, Log, Severity

pytestmark = pytest.mark.firmware

EV_DOWN, EV_NO_SWITCH, EV_NO_ENUM, EV_NO_CHIP, EV_STALLED = 2, 7, 8, 9, 10
AOA_PIPE_ERRORS = 8
HR_NAK = 0x4
USB_CHIP_DEAD = 2  # usb_host.h


@pytest.fixture
def stack():
    s = Stack()
    yield s
    s.close()


def _started(stack: Stack) -> int:
    return sum(e == EV_STARTED for e, _ in stack.events())


def test_a_phone_back_in_normal_mode_after_each_start_is_refused_after_a_few_tries(stack):
    stack.fault("never_switch", 2)
    passes = stack.run_until(REFUSED, 20_000)
    assert passes > 0, (stack.state, stack.events(), stack.last_error())
    assert stack.events() == [(EV_STARTED, 2)] * AOA_HANDSHAKE_TRIES + [(EV_NO_SWITCH, 2)]
    assert stack.stats()["detaches"] == AOA_HANDSHAKE_TRIES  # it did drop off after each START
    assert stack.lib.usbc_phone_mode() == PHONE_NORMAL
    # refused for good while it stays plugged in: no more START, no more events
    assert stack.step(3 * AOA_REENUM_US // PASS_US) == REFUSED
    assert len(stack.events()) == AOA_HANDSHAKE_TRIES + 1
    assert stack.last_error() == ""
    # unplugged and plugged in again: a new device with its tries again (this one switches)
    stack.fault("detach")
    assert stack.run_until(IDLE, 50) > 0
    stack.fault("never_switch", 0)
    stack.fault("attach")
    assert stack.run_until(RUNNING) > 0
    assert stack.events()[-2:] == [(EV_STARTED, 2), (EV_UP, stack.device()["pid"])]


@settings(max_examples=8, deadline=None)
@given(
    drops=st.lists(
        st.tuples(st.integers(1, 2500), st.integers(1, 400)), min_size=AOA_HANDSHAKE_TRIES, max_size=5
    )
)
def test_starts_are_bounded_whenever_the_phone_drops_off_and_comes_back_normal(drops):
    """Drawn moments: after each START the phone stays `ms_before` ms, then is away `ms_away` ms and comes
    back in its normal mode (all within AOA_REENUM_US): never more than AOA_HANDSHAKE_TRIES STARTs."""
    s = Stack()
    try:
        s.fault("never_switch", 1)
        for ms_before, ms_away in drops:
            before = _started(s)
            for _ in range(3000):
                if _started(s) > before or s.state == REFUSED:
                    break
                s.step()
            if s.state == REFUSED:
                break
            s.step(ms_before)
            s.fault("detach")
            s.step(ms_away)
            s.fault("attach")
        s.step(3 * AOA_REENUM_US // PASS_US)
        assert _started(s) <= AOA_HANDSHAKE_TRIES, s.events()
        assert s.state == REFUSED
        assert s.events()[-1] == (EV_NO_SWITCH, 2)
        assert s.last_error() == ""
    finally:
        s.close()


def test_a_bulk_endpoint_that_stalls_after_every_clear_is_refused_with_a_log(stack):
    assert stack.run_until(RUNNING) > 0
    before = stack.events()
    ep_out = stack.device()["bulk_out"]
    stack.board_write(b"queued for the phone" * 10)
    for _ in range(3000):  # 3 s: the phone halts its OUT endpoint again before every transaction
        stack.fault("stall", ep_out)
        stack.step()
    assert stack.stats()["stalls"] == AOA_PIPE_ERRORS  # then no more clearing, no more transactions
    assert stack.events()[len(before) :] == [(EV_DOWN, 0), (EV_STALLED, ep_out)]
    assert stack.state == REFUSED
    text = stack.event_text(EV_STALLED, ep_out)
    assert text == f"USB accessory refused: its bulk endpoint keeps stalling, 0x{ep_out:x}"
    # unplugged and plugged in again, a phone that behaves gets the stream
    stack.fault("detach")
    assert stack.run_until(IDLE, 50) > 0
    stack.fault("attach")
    assert stack.run_until(RUNNING) > 0
    stack.board_write(b"after the replug")
    _, phone = stack.pump(50)
    assert phone.endswith(b"after the replug")
    assert stack.last_error() == ""


def test_enumeration_that_keeps_failing_is_said_once_and_retried(stack):
    stack.fault("nak", 1e6)  # every data transaction NAKed: every control transfer times out
    stack.step(10_000)
    assert stack.stats()["enum_failures"] >= 2 * 3  # the host stack went on retrying
    assert stack.events() == [(EV_NO_ENUM, HR_NAK)]
    assert stack.state == IDLE  # not refusing: the retries go on
    text = stack.event_text(EV_NO_ENUM, HR_NAK)
    assert text == "USB device not enumerated, retrying every second; last HRSL 0x4"
    stack.fault("nak", 0)  # the device recovers: the next retry enumerates it
    assert stack.run_until(RUNNING, 5000) > 0
    assert stack.events()[1:] == [(EV_STARTED, 2), (EV_UP, stack.device()["pid"])]
    assert stack.last_error() == ""


def test_enumeration_failing_after_a_halt_that_could_not_be_cleared_is_said(stack):
    """The phone halts its OUT endpoint, STALLs the CLEAR_FEATURE and then NAKs every data stage: the board
    enumerates it again and that keeps failing. The endpoint the clear was for must not pass for "said"."""
    assert stack.run_until(RUNNING) > 0
    before = len(stack.events())
    stack.board_write(b"for the phone")
    stack.fault("stall", stack.device()["bulk_out"])
    stack.step(1)  # the OUT transaction STALLs: CLEAR_FEATURE(ENDPOINT_HALT) is next
    stack.fault("stall", 0)
    stack.fault("nak", 1e6)
    stack.step(10_000)
    assert [e for e, _ in stack.events()[before:]] == [EV_DOWN, EV_NO_ENUM]
    assert stack.events()[-1] == (EV_NO_ENUM, HR_NAK)
    assert stack.state == IDLE


def test_a_usb_chip_whose_oscillator_never_starts_is_said_once(stack):
    stack.fault("osc", 0)  # before the first pass: the chip's reset at start-up never ends
    stack.step(5000)
    assert stack.lib.usbc_host_state() == USB_CHIP_DEAD
    assert stack.events() == [(EV_NO_CHIP, 0)]
    assert stack.event_text(EV_NO_CHIP, 0) == "USB host chip (MAX3421E) not responding, retrying every second"
    stack.fault("osc", 1)
    assert stack.run_until(RUNNING, 5000) > 0
    assert stack.events()[1:] == [(EV_STARTED, 2), (EV_UP, stack.device()["pid"])]


def test_the_board_tells_the_phone_why_enumeration_failed():
    """The whole firmware: the refusal is an ERROR Log (code HANDSHAKE) queued while no accessory was open,
    read by the app once a phone enumerates."""
    with board() as b:
        usb(b, "detach")
        usb(b, "nak", "1000000")
        t0 = usb(b, "attach")
        end = time.monotonic() + 30.0
        while usb(b, "nak", "1000000") - t0 < 3.5:  # debounce + three tries of 3 transfers of 0.5 s
            assert time.monotonic() < end, "the board's clock did not get past the three tries"
            time.sleep(0.25)
        host = SerialHost(b.port)
        try:
            usb(b, "nak", "0")
            wait_mode(b, PHONE_ACCESSORY)
            log = host.wait_type(Log, 3.0, lambda m: m.code == LogCode.HANDSHAKE)
            assert log.severity == Severity.ERROR
            assert log.text == "USB device not enumerated, retrying every second; last HRSL 0x4"
            assert host.handshake().state == BoardState.DISARMED
        finally:
            host.close()

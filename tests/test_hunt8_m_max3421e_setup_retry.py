"""The MAX3421E model's SUDFIFO against the two ways real drivers retry a SETUP that got no handshake.

USB Host Shield 2.0 writes the 8 bytes once and launches HXFR again; Linux's max3421-hcd (and this
firmware, ``usb_host.c``'s ``CTL_SETUP``) writes them again before every launch. Both work on the chip, so
every SETUP sends SUDFIFO's 8 bytes from its start and the CPU's next write starts there too. The model
restarted the pointer only at a SETUP the phone took: a rewrite after one that timed out (the phone
unplugged, or plugged back and not yet reset) was reported as "SUDFIFO written past 8 bytes" - a protocol
violation by a driver that made none, seen by the replug tests of the firmware at drawn moments.

Driven through the model's SPI bytes on simulated time (``tests/max3421e_support.py``)."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from max3421e_support import (
    HCTL,
    HIRQ,
    HRSL,
    HXFR,
    HXFRDNIRQ,
    RCVBC,
    RCVDAVIRQ,
    RCVFIFO,
    RCVTOG1,
    SUCCESS,
    SUDFIFO,
    TIMEOUT,
    TOK_HSOUT,
    TOK_IN,
    TOK_SETUP,
    Chip,
    library,
)

pytestmark = pytest.mark.firmware

GET_DEVICE_DESCRIPTOR = bytes([0x80, 6, 0, 1, 0, 0, 18, 0])


@pytest.fixture(scope="module", autouse=True)
def _built() -> None:
    library()


def _launch(chip: Chip) -> int:
    chip.wr(HXFR, TOK_SETUP)
    chip.wait(HIRQ, HXFRDNIRQ, timeout_us=1000)
    chip.wr(HIRQ, HXFRDNIRQ)
    return chip.rd(HRSL) & 0x0F


@settings(max_examples=20, deadline=None)
@given(timeouts=st.integers(1, 5), rewrite=st.booleans())
def test_a_setup_retried_after_timeouts_is_no_violation_either_way(timeouts, rewrite):
    chip = Chip()
    try:
        chip.start()
        chip.fault("detach")  # the phone gone: every SETUP times out, no handshake
        chip.wr_bytes(SUDFIFO, GET_DEVICE_DESCRIPTOR)
        for _ in range(timeouts):
            assert _launch(chip) == TIMEOUT
            if rewrite:  # the Linux driver's (and this firmware's) way: the 8 bytes again before each launch
                chip.wr_bytes(SUDFIFO, GET_DEVICE_DESCRIPTOR)
        chip.fault("attach")
        chip.bus_reset()
        assert _launch(chip) == SUCCESS  # USB Host Shield's way when not rewritten: the bytes kept
        chip.wr(HCTL, RCVTOG1)  # the data stage starts with DATA1
        data = b""
        while len(data) < 18:
            assert chip.xfer_retry(TOK_IN) == SUCCESS
            data += chip.rd_bytes(RCVFIFO, chip.rd(RCVBC))
            chip.wr(HIRQ, RCVDAVIRQ)
        assert chip.xfer_retry(TOK_HSOUT) == SUCCESS
        assert data[0] == 18 and data[1] == 1  # the request the SETUP carried: a device descriptor
        assert chip.last_error() == ""
    finally:
        chip.close()


def test_more_than_eight_bytes_before_a_setup_is_still_a_violation():
    chip = Chip()
    try:
        chip.start()
        chip.wr_bytes(SUDFIFO, GET_DEVICE_DESCRIPTOR)
        chip.wr_bytes(SUDFIFO, GET_DEVICE_DESCRIPTOR[:1])
        assert "SUDFIFO written past 8" in chip.last_error()
    finally:
        chip.close()

"""The harness's MAX3421E + Android phone model (firmware/harness/max3421e.c) at register level, through
ctypes: every test speaks the chip's SPI commands and moves simulated microseconds, as the firmware does
under simavr, and checks what a USB host would see (HIRQ, HRSL, RCVFIFO) and what the phone recorded."""

from __future__ import annotations

import struct

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from max3421e_support import (
    BADREQ,
    BUSEVENTIRQ,
    BUSRST,
    BUSY,
    CHIPRES,
    CONDETIRQ,
    CPUCTL,
    DMPULLDN,
    DPPULLDN,
    FDUPSPI,
    FRAMEIRQ,
    HCTL,
    HIEN,
    HIRQ,
    HOST,
    HRSL,
    HXFR,
    HXFRDNIRQ,
    IE,
    INTLEVEL,
    JSTATUS,
    KSTATUS,
    LOWSPEED,
    MODE,
    NAK,
    OSCOKIRQ,
    PERADDR,
    PINCTL,
    RCVBC,
    RCVDAVIRQ,
    RCVFIFO,
    RCVTOG0,
    RCVTOG1,
    RCVTOGRD,
    REVISION,
    SAMPLEBUS,
    SNDBAVIRQ,
    SNDTOG0,
    SNDTOG1,
    SNDTOGRD,
    SOFKAENAB,
    STALL,
    SUCCESS,
    SUDFIFO,
    TIMEOUT,
    TOGERR,
    TOK_HSIN,
    TOK_IN,
    TOK_OUT,
    TOK_SETUP,
    USBCTL,
    USBIRQ,
    Chip,
    UsbError,
)

from protocol import aoa
from protocol.errors import ProtocolError

pytestmark = pytest.mark.firmware

ACC_IN, ACC_OUT = 1, 2  # the accessory's bulk endpoints (0x81, 0x02) as its descriptor names them
IDENTITY = aoa.AccessoryIdentity("VSCMG-HIL", "ADK bridge", "ADCS bench", "1.0", "https://x.invalid", "SN42")


@pytest.fixture
def chip():
    c = Chip()
    yield c
    c.close()


def parse_endpoints(cfg: bytes, interface: int) -> list[tuple[int, int, int]]:
    """(address, attributes, max packet) of each endpoint of ``interface`` in a configuration descriptor."""
    eps, current, k = [], None, 0
    while k < len(cfg):
        length, kind = cfg[k], cfg[k + 1]
        if kind == 4:
            current = cfg[k + 2]
        elif kind == 5 and current == interface:
            eps.append((cfg[k + 2], cfg[k + 3], struct.unpack_from("<H", cfg, k + 4)[0]))
        k += length
    return eps


def aoa_switch(c: Chip) -> int:
    """protocol.aoa's whole switch (GET_PROTOCOL, six SEND_STRINGs, START) as control transfers; the
    version the phone reported."""
    version = 0
    for t in aoa.start_sequence(IDENTITY):
        if t.is_in:
            answer = c.control_read(t.bmRequestType, t.bRequest, t.wValue, t.wIndex, t.wLength)
            version = aoa.parse_protocol_version(answer)
        else:
            c.control_write(t.bmRequestType, t.bRequest, t.wValue, t.wIndex, t.data)
    return version


def to_accessory(c: Chip) -> bytes:
    """Enumerate the phone, switch it, wait for it to come back, enumerate it again at address 2; the
    accessory-mode device descriptor."""
    c.start()
    c.enumerate(1)
    assert aoa_switch(c) == 2
    c.wr(HIRQ, CONDETIRQ)
    c.wait(HIRQ, CONDETIRQ, timeout_us=20_000, step_us=100)  # dropped off
    assert c.mode() == 0
    c.wr(HIRQ, CONDETIRQ)
    c.wait(HIRQ, CONDETIRQ, timeout_us=200_000, step_us=500)  # back, as an accessory
    assert c.mode() == 2
    c.bus_reset()
    return c.enumerate(2)


# --------------------------------------------------------------------------- chip
def test_revision_reads_only_in_full_duplex_spi(chip):
    # Until PINCTL.FDUPSPI, MISO is unused: a read sees the idle line, and the model says why.
    assert chip.rd(REVISION) == 0xFF
    assert "half-duplex" in chip.last_error()
    chip.wr(PINCTL, FDUPSPI | INTLEVEL)
    assert chip.rd(REVISION) == 0x13
    assert chip.rd(PINCTL) == FDUPSPI | INTLEVEL


def test_status_byte_is_hirq(chip):
    chip.wr(PINCTL, FDUPSPI)
    chip.rd(REVISION)
    assert chip.status == chip.rd(HIRQ) == SNDBAVIRQ  # after reset: the send buffer is free, nothing else


def test_chipres_keeps_pinctl_and_restarts_the_oscillator(chip):
    chip.wr(PINCTL, FDUPSPI | INTLEVEL)
    chip.advance(1000)
    assert chip.rd(USBIRQ) & OSCOKIRQ  # running since power-up
    chip.wr(USBIRQ, OSCOKIRQ)
    chip.wr(MODE, HOST)
    chip.wr(USBCTL, CHIPRES)
    chip.advance(5000)
    assert not chip.rd(USBIRQ) & OSCOKIRQ  # held in reset: no oscillator
    assert chip.rd(MODE) == 0  # registers reset ...
    assert chip.rd(PINCTL) == FDUPSPI | INTLEVEL  # ... but not the SPI's configuration
    chip.wr(USBCTL, 0)
    waited = chip.wait(USBIRQ, OSCOKIRQ, timeout_us=5000)
    assert 100 <= waited <= 1000


def test_res_pin_resets_everything_and_ignores_spi(chip):
    chip.wr(PINCTL, FDUPSPI)
    chip.lib.max3421e_reset_pin(chip.m, 1)
    chip.wr(MODE, HOST)  # ignored: the chip is held in reset
    assert "SS high" in chip.last_error()
    chip.lib.max3421e_reset_pin(chip.m, 0)
    assert chip.rd(REVISION) == 0xFF  # PINCTL reset too: half duplex again
    chip.wr(PINCTL, FDUPSPI)
    assert chip.rd(MODE) == 0
    chip.wait(USBIRQ, OSCOKIRQ, timeout_us=5000)


def test_int_pin_follows_enabled_irqs(chip):
    chip.start()
    chip.wr(HIRQ, 0xFF)
    chip.wr(HIEN, FRAMEIRQ)
    assert not chip.int_asserted()  # CPUCTL.IE still off
    chip.wr(CPUCTL, IE)
    chip.advance(1001)
    assert chip.int_asserted()
    chip.wr(HIRQ, FRAMEIRQ)
    assert not chip.int_asserted()
    chip.wr(HIEN, 0)
    chip.advance(3000)
    assert chip.rd(HIRQ) & FRAMEIRQ and not chip.int_asserted()


def test_bus_sample_sees_a_full_speed_device_then_se0_after_detach(chip):
    chip.start(reset_bus=False)
    chip.wr(HCTL, SAMPLEBUS)
    assert chip.rd(HCTL) & SAMPLEBUS  # reads back set once the sample is taken
    assert chip.rd(HRSL) & (JSTATUS | KSTATUS) == JSTATUS  # D+ high: full speed
    chip.wr(HIRQ, CONDETIRQ)
    assert chip.fault("detach") == 0
    assert chip.rd(HIRQ) & CONDETIRQ
    chip.wr(HCTL, SAMPLEBUS)
    assert chip.rd(HRSL) & (JSTATUS | KSTATUS) == 0  # SE0
    chip.wr(HIRQ, CONDETIRQ)
    assert chip.fault("attach") == 0
    assert chip.rd(HIRQ) & CONDETIRQ and chip.mode() == 1


def test_bus_reset_lasts_50ms_and_frames_tick_every_ms(chip):
    chip.start(reset_bus=False)
    chip.wr(HCTL, BUSRST)
    t0 = chip.now
    chip.wait(HIRQ, BUSEVENTIRQ, timeout_us=100_000, step_us=100)
    assert 49_900 <= chip.now - t0 <= 50_100
    assert not chip.rd(HCTL) & BUSRST  # cleared by the chip when done
    chip.wr(HIRQ, FRAMEIRQ)
    gaps = []
    for _ in range(3):
        gaps.append(chip.wait(HIRQ, FRAMEIRQ, timeout_us=2000, step_us=10))
        chip.wr(HIRQ, FRAMEIRQ)
    assert all(abs(g - 1000) <= 20 for g in gaps[1:])
    chip.wr(MODE, DPPULLDN | DMPULLDN | HOST)  # SOFs off: no more frames
    chip.advance(5000)
    assert not chip.rd(HIRQ) & FRAMEIRQ


def test_device_answers_nothing_before_a_bus_reset(chip):
    chip.start(reset_bus=False)
    chip.wr_bytes(SUDFIFO, bytes([0x80, 6, 0, 1, 0, 0, 18, 0]))
    assert chip.xfer(TOK_SETUP) == TIMEOUT
    assert "bus reset" in chip.last_error()


def test_transfer_takes_simulated_time(chip):
    chip.start()
    chip.wr_bytes(SUDFIFO, bytes([0x80, 6, 0, 1, 0, 0, 18, 0]))
    chip.wr(HXFR, TOK_SETUP)
    assert not chip.rd(HIRQ) & HXFRDNIRQ  # nothing is instantaneous
    chip.wr(HXFR, TOK_SETUP)  # a second launch while busy is a driver bug
    assert "in progress" in chip.last_error()
    waited = chip.wait(HIRQ, HXFRDNIRQ, step_us=1)
    assert 5 <= waited <= 30
    assert chip.rd(HRSL) & 0x0F == SUCCESS


# --------------------------------------------------------------------------- control transfers
def test_get_device_descriptor_by_hand(chip):
    chip.start()
    chip.wr_bytes(SUDFIFO, bytes([0x80, 6, 0, 1, 0, 0, 64, 0]))  # GET_DESCRIPTOR(device), wLength 64
    assert chip.xfer(TOK_SETUP) == SUCCESS
    chip.wr(HCTL, RCVTOG1)  # the data stage starts with DATA1
    assert chip.xfer(TOK_IN) == SUCCESS
    assert chip.rd(HIRQ) & RCVDAVIRQ
    n = chip.rd(RCVBC)
    desc = chip.rd_bytes(RCVFIFO, n)
    chip.wr(HIRQ, RCVDAVIRQ)
    assert not chip.rd(HIRQ) & RCVDAVIRQ
    assert chip.rd(HRSL) & RCVTOGRD == 0  # flipped to DATA0 for the next packet
    assert chip.xfer(0xA0) == SUCCESS  # HS-OUT: status stage
    assert n == 18 and desc[0] == 18 and desc[1] == 1
    vid, pid = struct.unpack_from("<HH", desc, 8)
    assert (vid, pid) == (0x04E8, 0x6860)  # a Samsung phone in its normal mode
    assert desc[7] == 64  # ep0 max packet
    assert chip.last_error() == ""


def test_short_wlength_truncates_and_config_spans_packets(chip):
    chip.start()
    assert len(chip.control_read(0x80, 6, 0x0100, 0, 8)) == 8
    head = chip.control_read(0x80, 6, 0x0200, 0, 9)
    total = struct.unpack_from("<H", head, 2)[0]
    cfg = chip.control_read(0x80, 6, 0x0200, 0, total)
    assert len(cfg) == total == 62
    assert parse_endpoints(cfg, 1) == [(0x83, 2, 64), (0x02, 2, 64)]  # ADB
    lang = chip.control_read(0x80, 6, 0x0300, 0, 255)
    assert lang == bytes([4, 3, 0x09, 0x04])
    man = chip.control_read(0x80, 6, 0x0301, 0x0409, 255)
    assert man[2:].decode("utf-16-le") == "samsung"


def test_wrong_toggle_on_in_is_togerr(chip):
    chip.start()
    chip.setup(0x80, 6, 0x0100, 0, 18)
    chip.wr(HCTL, RCVTOG0)  # wrong: the data stage's first packet is DATA1
    assert chip.xfer(TOK_IN) == TOGERR
    assert "DATA1 received, RCVTOG expected DATA0" in chip.last_error()
    assert not chip.rd(HIRQ) & RCVDAVIRQ


def test_wrong_toggle_on_out_is_discarded_by_the_device(chip):
    c = chip
    c.start()
    c.enumerate(1)
    c.setup(0x40, 52, 0, 0, 4)
    c.wr(HCTL, SNDTOG0)  # wrong: DATA1 expected
    assert c.send(0, b"abc\x00") == SUCCESS  # the device ACKs a repeat ...
    assert "expected DATA1" in c.last_error()
    assert c.rd(HRSL) & SNDTOGRD  # the chip flipped, thinking it delivered
    assert c.xfer(TOK_HSIN) == STALL  # ... but it never got the data: the status stage fails
    assert c.string(0) == ""


def test_nak_fault_then_retry_succeeds(chip):
    chip.start()
    assert chip.fault("nak", 3) == 0
    chip.setup(0x80, 6, 0x0100, 0, 18)  # a SETUP is never NAKed
    chip.wr(HCTL, RCVTOG1)
    codes = [chip.xfer(TOK_IN) for _ in range(4)]
    assert codes == [NAK, NAK, NAK, SUCCESS]
    assert chip.rd(RCVBC) == 18


def test_stall_fault_on_ep0_clears_with_the_next_setup(chip):
    chip.start()
    assert chip.fault("stall", 0) == 0
    chip.setup(0x80, 6, 0x0100, 0, 18)
    chip.wr(HCTL, RCVTOG1)
    assert chip.xfer(TOK_IN) == STALL
    assert chip.xfer(TOK_IN) == STALL  # a protocol stall lasts until the next SETUP
    assert len(chip.control_read(0x80, 6, 0x0100, 0, 18)) == 18


def test_unknown_request_stalls(chip):
    chip.start()
    chip.setup(0x80, 6, 0x0600, 0, 10)  # device qualifier: a full-speed-only device has none
    chip.wr(HCTL, RCVTOG1)
    assert chip.xfer(TOK_IN) == STALL


def test_set_address_then_only_the_new_address_answers(chip):
    chip.start()
    chip.control_write(0x00, 5, 7, 0)
    chip.wr(PERADDR, 0)
    chip.wr_bytes(SUDFIFO, bytes([0x80, 6, 0, 1, 0, 0, 18, 0]))
    assert chip.xfer(TOK_SETUP) == TIMEOUT
    assert "address 7" in chip.last_error()
    chip.wr(PERADDR, 7)
    assert chip.control_read(0x80, 6, 0x0100, 0, 18)[0] == 18


def test_set_address_takes_effect_after_the_status_stage(chip):
    chip.start()
    chip.setup(0x00, 5, 9, 0, 0)
    chip.wr(PERADDR, 0)  # the status stage still goes to the old address
    assert chip.xfer(TOK_HSIN) == SUCCESS
    chip.wr(PERADDR, 9)
    assert len(chip.control_read(0x80, 6, 0x0100, 0, 18)) == 18


def test_low_speed_mode_against_a_full_speed_phone_times_out(chip):
    chip.start()
    chip.wr(MODE, DPPULLDN | DMPULLDN | HOST | SOFKAENAB | LOWSPEED)
    chip.wr_bytes(SUDFIFO, bytes(8))
    assert chip.xfer(TOK_SETUP) == TIMEOUT
    assert "LOWSPEED" in chip.last_error()


def test_bad_token_is_badreq(chip):
    chip.start()
    chip.wr(HXFR, 0x30)
    chip.wait(HIRQ, HXFRDNIRQ)
    assert chip.rd(HRSL) & 0x0F == BADREQ


# --------------------------------------------------------------------------- AOA
def test_aoa_switch_records_strings_and_reenumerates_as_accessory(chip):
    desc = to_accessory(chip)
    assert struct.unpack_from("<HH", desc, 8) == (0x18D1, 0x2D01)
    for index, text in IDENTITY.strings():
        assert chip.string(int(index)) == text
    total = struct.unpack_from("<H", chip.control_read(0x80, 6, 0x0200, 0, 9), 2)[0]
    cfg = chip.control_read(0x80, 6, 0x0200, 0, total)
    assert parse_endpoints(cfg, aoa.ACCESSORY_INTERFACE) == [(0x81, 2, 64), (0x02, 2, 64)]
    assert chip.last_error() == ""


def test_phone_without_aoa_reports_version_0_and_stalls_the_rest(chip):
    chip.fault("aoa", 0)
    chip.start()
    chip.enumerate(1)
    answer = chip.control_read(0xC0, 51, 0, 0, 2)
    assert answer == b"\x00\x00"
    with pytest.raises(ProtocolError, match="does not support"):
        aoa.parse_protocol_version(answer)
    with pytest.raises(UsbError) as e:
        chip.control_write(0x40, 53, 0, 0)
    assert e.value.code == STALL
    chip.advance(200_000)
    assert chip.mode() == 1  # never switched


def test_send_string_without_terminator_is_reported(chip):
    chip.start()
    chip.enumerate(1)
    chip.control_write(0x40, 52, 0, 1, b"model")
    assert chip.string(1) == "model"
    assert "terminating zero" in chip.last_error()
    with pytest.raises(UsbError):
        chip.control_write(0x40, 52, 0, 6, b"x\x00")  # index 6 does not exist


def test_phone_rejects_app_writes_until_accessory(chip):
    chip.start()
    chip.enumerate(1)
    assert chip.phone_write(b"hello") == 0  # no accessory open yet


def test_bulk_in_and_out_with_toggles(chip):
    to_accessory(chip)
    assert chip.receive(ACC_IN) is None  # nothing queued: NAK
    assert chip.phone_write(b"frame-one") == 9
    chip.wr(HCTL, RCVTOG0 | SNDTOG0)  # after SET_CONFIGURATION every bulk endpoint starts at DATA0
    assert chip.receive(ACC_IN) == b"frame-one"
    assert chip.rd(HRSL) & RCVTOGRD
    assert chip.phone_write(b"two") == 3
    assert chip.receive(ACC_IN) == b"two"
    assert chip.send(ACC_OUT, b"telemetry") == SUCCESS
    assert chip.send(ACC_OUT, b"-more") == SUCCESS
    assert chip.phone_read() == b"telemetry-more"
    assert chip.last_error() == ""
    # the wrong toggle on bulk OUT: acknowledged, discarded, reported
    chip.wr(HCTL, SNDTOG1)
    assert chip.send(ACC_OUT, b"repeat?") == SUCCESS
    assert chip.phone_read() == b"" and "discarded" in chip.last_error()


def test_bulk_endpoints_not_in_the_config_time_out(chip):
    to_accessory(chip)
    chip.wr(HCTL, RCVTOG0)
    assert chip.xfer(TOK_IN, ACC_OUT) == TIMEOUT  # endpoint 2 is OUT only
    assert "no IN endpoint 2" in chip.last_error()


def test_bulk_before_set_configuration_times_out(chip):
    chip.start()
    chip.control_read(0x80, 6, 0x0100, 0, 18)
    assert chip.xfer(TOK_IN, 1) == TIMEOUT
    assert "SET_CONFIGURATION" in chip.last_error()


def test_stall_fault_on_bulk_in_once(chip):
    to_accessory(chip)
    chip.phone_write(b"x")
    chip.fault("stall", ACC_IN)
    chip.wr(HCTL, RCVTOG0)
    assert chip.xfer(TOK_IN, ACC_IN) == STALL
    chip.control_write(0x02, 1, 0, 0x81)  # CLEAR_FEATURE(ENDPOINT_HALT): the toggle restarts
    assert chip.receive(ACC_IN) == b"x"


def test_packet_fault_splits_and_zlp_ends_whole_packets(chip):
    to_accessory(chip)
    chip.wr(HCTL, RCVTOG0)
    chip.fault("packet", 10)
    chip.phone_write(bytes(range(25)))
    sizes = [len(chip.receive(ACC_IN)) for _ in range(3)]
    assert sizes == [10, 10, 5]
    chip.fault("packet", 64)
    chip.fault("zlp", 1)
    chip.phone_write(bytes(128))
    chip.phone_write(b"next")
    got = [chip.receive(ACC_IN) for _ in range(4)]
    assert [len(g) for g in got] == [64, 64, 0, 4]  # a transfer of whole packets ends with a ZLP


def test_rcvfifo_double_buffer(chip):
    to_accessory(chip)
    chip.wr(HCTL, RCVTOG0)
    chip.fault("packet", 4)
    chip.phone_write(b"aaaabbbbcccc")
    assert chip.xfer(TOK_IN, ACC_IN) == SUCCESS
    assert chip.xfer(TOK_IN, ACC_IN) == SUCCESS  # into the second buffer
    assert chip.xfer(TOK_IN, ACC_IN) == BUSY  # both full: RCVDAVIRQ never cleared
    assert "both RCVFIFO buffers full" in chip.last_error()
    assert chip.rd_bytes(RCVFIFO, chip.rd(RCVBC)) == b"aaaa"
    chip.wr(HIRQ, RCVDAVIRQ)
    assert chip.rd(HIRQ) & RCVDAVIRQ  # the second buffer shows at once
    assert chip.rd_bytes(RCVFIFO, chip.rd(RCVBC)) == b"bbbb"
    chip.wr(HIRQ, RCVDAVIRQ)
    assert not chip.rd(HIRQ) & RCVDAVIRQ
    assert chip.receive(ACC_IN) == b"cccc"


def test_bulk_out_naks_when_the_app_does_not_read(chip):
    to_accessory(chip)
    chip.wr(HCTL, SNDTOG0)
    sent = 0
    while chip.send(ACC_OUT, bytes(64)) == SUCCESS:
        sent += 64
        assert sent <= 1 << 20
    assert sent == 4096  # the phone's buffer, then flow control: NAK, nothing lost
    assert chip.rd(HRSL) & 0x0F == NAK
    assert not chip.rd(HIRQ) & SNDBAVIRQ  # the packet stays loaded for the retry
    assert len(chip.phone_read(100_000)) == 4096
    assert chip.xfer(TOK_OUT, ACC_OUT) == SUCCESS  # the same packet, again
    assert chip.rd(HIRQ) & SNDBAVIRQ


def test_app_writes_are_bounded(chip):
    to_accessory(chip)
    assert chip.phone_write(bytes(5000)) == 4096
    assert chip.phone_write(b"more") == 0


def test_detach_mid_run_then_reattach_in_normal_mode(chip):
    to_accessory(chip)
    chip.phone_write(b"lost")
    chip.wr(HIRQ, CONDETIRQ)
    chip.fault("detach")
    assert chip.rd(HIRQ) & CONDETIRQ and chip.mode() == 0
    chip.wr(HCTL, RCVTOG0)
    assert chip.xfer(TOK_IN, ACC_IN) == TIMEOUT  # nobody there
    chip.wr(HIRQ, CONDETIRQ)
    chip.fault("attach")
    assert chip.rd(HIRQ) & CONDETIRQ and chip.mode() == 1
    chip.bus_reset()
    desc = chip.enumerate(1)
    assert struct.unpack_from("<HH", desc, 8) == (0x04E8, 0x6860)  # a re-plugged phone starts normal
    assert aoa_switch(chip) == 2  # the whole switch again
    chip.advance(100_000)
    assert chip.mode() == 2


def test_unknown_faults_are_refused(chip):
    assert chip.fault("bogus", 1) == -1
    assert chip.fault("aoa", 3) == -1
    assert chip.fault("packet", 0) == -1
    assert chip.fault("packet", 65) == -1
    assert chip.fault("stall", 1.5) == -1


def test_fifo_misuse_is_reported_not_fatal(chip):
    chip.start()
    chip.wr_bytes(SUDFIFO, bytes(9))
    assert "SUDFIFO written past 8" in chip.last_error()
    chip.rd_bytes(RCVFIFO, 3)
    assert "RCVFIFO read past RCVBC" in chip.last_error()
    chip.wr(REVISION, 0)
    assert "read-only" in chip.last_error()
    assert chip.rd(REVISION) == 0x13


# --------------------------------------------------------------------------- property
@settings(max_examples=40, deadline=None)
@given(
    writes=st.lists(st.binary(min_size=1, max_size=200), min_size=1, max_size=8),
    packet=st.integers(1, 64),
    naks=st.integers(0, 3),
    zlp=st.booleans(),
)
def test_app_bytes_arrive_on_bulk_in_in_order(writes, packet, naks, zlp):
    c = Chip()
    try:
        to_accessory(c)
        c.fault("packet", packet)
        c.fault("nak", naks)
        c.fault("zlp", int(zlp))
        c.wr(HCTL, RCVTOG0)
        want = b"".join(writes)
        got = b""
        for w in writes:
            assert c.phone_write(w) == len(w)
        idle = 0
        while idle <= naks + 1:
            data = c.receive(ACC_IN)
            if data is None:
                idle += 1
                continue
            idle = 0
            assert len(data) <= packet
            got += data
        assert got == want
        assert c.last_error() == ""
    finally:
        c.close()


def test_in_wire_time_depends_on_the_answer(chip):
    to_accessory(chip)
    chip.wr(HCTL, RCVTOG0)

    def timed_in() -> tuple[int, int]:
        chip.wr(HXFR, TOK_IN | ACC_IN)
        waited = chip.wait(HIRQ, HXFRDNIRQ, step_us=1)
        chip.wr(HIRQ, HXFRDNIRQ)
        return chip.rd(HRSL) & 0x0F, waited

    code, nak_us = timed_in()
    assert code == NAK and nak_us <= 10  # token and handshake only
    chip.phone_write(bytes(64))
    code, full_us = timed_in()
    assert code == SUCCESS and 45 <= full_us <= 60  # plus 64 bytes at 12 Mb/s
    chip.wr(HIRQ, RCVDAVIRQ)
    chip.phone_write(bytes(64))
    chip.wr(HXFR, TOK_IN | ACC_IN)
    chip.advance(20)  # the device has answered: its data packet is on the wire ...
    assert not chip.rd(HIRQ) & HXFRDNIRQ
    chip.fault("detach")  # ... when the cable is pulled
    chip.wait(HIRQ, HXFRDNIRQ, step_us=1)
    assert chip.rd(HRSL) & 0x0F == TIMEOUT and not chip.rd(HIRQ) & RCVDAVIRQ


@settings(max_examples=30, deadline=None)
@given(
    chunks=st.lists(st.binary(min_size=0, max_size=64), min_size=1, max_size=20),
    naks=st.integers(0, 3),
    read_cap=st.integers(1, 100),
)
def test_board_bytes_reach_the_app_in_order(chunks, naks, read_cap):
    # bulk OUT under NAK storms, the app reading in small bites: nothing lost, nothing repeated
    c = Chip()
    try:
        to_accessory(c)
        c.fault("nak", naks)
        c.wr(HCTL, SNDTOG0)
        got = b""
        for chunk in chunks:
            code = c.send(ACC_OUT, chunk)
            while code == NAK:
                code = c.xfer(TOK_OUT, ACC_OUT)  # the same loaded packet, again
            assert code == SUCCESS
            got += c.phone_read(read_cap)
        got += c.phone_read(1 << 16)
        assert got == b"".join(chunks)
        assert c.last_error() == ""
    finally:
        c.close()


_OPS = st.one_of(
    st.tuples(st.just("cmd"), st.integers(0, 255), st.binary(max_size=70)),
    st.tuples(st.just("advance"), st.integers(0, 60_000)),
    st.tuples(st.just("fault"), st.sampled_from(["nak", "stall", "detach", "attach", "aoa", "packet", "zlp"]),
              st.integers(-1, 70)),
    st.tuples(st.just("write"), st.binary(max_size=300)),
    st.tuples(st.just("read"), st.integers(0, 5000)),
    st.tuples(st.just("res"), st.booleans()),
    st.tuples(st.just("stray"), st.integers(0, 255)),
)  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(ops=st.lists(_OPS, max_size=60), started=st.booleans())
def test_any_spi_traffic_is_survived(ops, started):
    # Whatever a buggy driver clocks in, in whatever order: no crash, the state stays one of the documented
    # ones, and the chip still answers a proper start afterwards.
    c = Chip()
    try:
        if started:
            c.start()
        for op in ops:
            kind = op[0]
            if kind == "cmd":
                c.command(op[1] >> 3, bool(op[1] & 2), op[2], nread=len(op[2]))
            elif kind == "advance":
                c.advance(op[1])
            elif kind == "fault":
                c.fault(op[1], op[2])
            elif kind == "write":
                assert c.phone_write(op[1]) <= len(op[1])
            elif kind == "read":
                assert len(c.phone_read(op[1])) <= op[1] if op[1] else True
            elif kind == "res":
                c.lib.max3421e_reset_pin(c.m, int(op[1]))
            else:
                c.lib.max3421e_spi(c.m, op[1])  # a byte with SS high
            assert c.mode() in (0, 1, 2)
            assert len(c.last_error()) < 200
        c.lib.max3421e_reset_pin(c.m, 0)
        c.fault("attach")
        c.fault("nak", 0)
        c.fault("stall", 15)  # moves a pending one-shot STALL off endpoint 0, to an endpoint nobody uses
        c.start()
        assert c.rd(REVISION) == 0x13
        assert len(c.control_read(0x80, 6, 0x0100, 0, 18)) == 18
    finally:
        c.close()


def test_only_an_edge_of_ss_starts_a_command(chip):
    chip.wr(PINCTL, FDUPSPI)
    lib, m = chip.lib, chip.m
    lib.max3421e_select(m, 1)
    lib.max3421e_spi(m, REVISION << 3)
    lib.max3421e_select(m, 1)  # SS re-driven low (another pin of port B written): the same command goes on
    assert lib.max3421e_spi(m, 0) == 0x13
    lib.max3421e_select(m, 0)

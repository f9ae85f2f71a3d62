"""The firmware's USB host stack (firmware/src/max3421e.c, usb_host.c, aoa.c) on the host, driven through
ctypes (``firmware/build/libusb-check.so``) against the MAX3421E + Android phone model
(``firmware/harness/max3421e.c``) on simulated time: enumeration, the Android Open Accessory handshake
with the board's identity strings, AOA version 0 refused with a log, NAK storms, STALLs, detach and
re-attach, and the bytes of the bulk pipes in order across packet boundaries and zero-length packets.

Every pass of the stack stands for one main-loop pass of the board (``PASS_US`` apart); the model's
``last_error`` (a protocol violation by the board) must stay empty throughout."""

from __future__ import annotations

import ctypes
import functools
import re
import struct

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, given, settings

from firmware_sim.avr import eeprom
from firmware_sim.avr.build import ensure_built
from firmware_sim.avr.hostlib import config_parse
from firmware_sim.avr.paths import BUILD_DIR, FIRMWARE_DIR
from firmware_sim.board.config import BoardConfig
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError
from protocol.frame import Frame, decode_stream, encode_frame
from protocol.messages import Heartbeat, Log, Severity

pytestmark = pytest.mark.firmware

PASS_US = 1000  # the board's main loop runs at least once per 1 ms tick
# aoa.h's states
IDLE, HANDSHAKE, WAIT_REENUM, RUNNING, CLEAR_HALT, REFUSED = range(6)
# usb_host.h's states
USB_DETACHED, USB_CONFIGURED = 3, 8
# aoa.h's events
EV_UP, EV_DOWN, EV_NO_AOA, EV_STARTED, EV_FAILED, EV_NO_PIPES, EV_NO_SWITCH = 1, 2, 3, 4, 5, 6, 7
AOA_HANDSHAKE_TRIES = 3
AOA_REENUM_US = 3_000_000  # after START, how long the board waits for the phone to come back
# the phone's modes (harness/max3421e.h)
PHONE_DETACHED, PHONE_NORMAL, PHONE_ACCESSORY = 0, 1, 2
# attach debounce 200 ms + bus reset 50 ms + recovery 20 ms + enumeration, twice (normal, accessory)
ENUMERATION_PASSES = 2000


@functools.cache
def _lib() -> ctypes.CDLL:
    ensure_built()
    lib = ctypes.CDLL(str(BUILD_DIR / "libusb-check.so"))
    u8p, u16p = ctypes.POINTER(ctypes.c_uint8), ctypes.POINTER(ctypes.c_uint16)
    for name, res, args in [
        ("usbc_open", ctypes.c_int, [ctypes.c_char_p]),
        ("usbc_close", None, []),
        ("usbc_now", ctypes.c_uint64, []),
        ("usbc_step", ctypes.c_int, [ctypes.c_uint32]),
        ("usbc_run_until", ctypes.c_long, [ctypes.c_int, ctypes.c_uint32, ctypes.c_uint32]),
        ("usbc_host_state", ctypes.c_int, []),
        ("usbc_version", ctypes.c_int, []),
        ("usbc_fault", ctypes.c_int, [ctypes.c_char_p, ctypes.c_double]),
        ("usbc_board_write", ctypes.c_size_t, [u8p, ctypes.c_size_t]),
        ("usbc_board_read", ctypes.c_size_t, [u8p, ctypes.c_size_t]),
        ("usbc_board_tx_pending", ctypes.c_size_t, []),
        ("usbc_phone_write", ctypes.c_size_t, [u8p, ctypes.c_size_t]),
        ("usbc_phone_read", ctypes.c_size_t, [u8p, ctypes.c_size_t]),
        ("usbc_phone_mode", ctypes.c_int, []),
        ("usbc_phone_string", ctypes.c_char_p, [ctypes.c_int]),
        ("usbc_last_error", ctypes.c_char_p, []),
        ("usbc_events", ctypes.c_int, [u8p, u16p, ctypes.c_int]),
        ("usbc_event_text", None, [ctypes.c_uint8, ctypes.c_uint16, ctypes.c_char_p, ctypes.c_uint8]),
        ("usbc_stats", None, [u16p]),
        ("usbc_device", None, [u16p]),
        ("usbc_max_pass_us", ctypes.c_uint32, []),
    ]:
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


def _buf(data: bytes) -> ctypes.Array:
    return (ctypes.c_uint8 * max(1, len(data))).from_buffer_copy(data or b"\0")


class Stack:
    """The one USB stack of the library (its state is static, as on the board)."""

    def __init__(self, serial: str = "LAB-01") -> None:
        self.lib = _lib()
        assert self.lib.usbc_open(serial.encode()) == 0

    def close(self) -> None:
        self.lib.usbc_close()

    def step(self, n: int = 1) -> int:
        state = -1
        for _ in range(n):
            state = self.lib.usbc_step(PASS_US)
        return state

    def run_until(self, state: int, passes: int = ENUMERATION_PASSES) -> int:
        return self.lib.usbc_run_until(state, PASS_US, passes)

    def fault(self, name: str, value: float = 0.0) -> None:
        assert self.lib.usbc_fault(name.encode(), value) == 0, name

    @property
    def state(self) -> int:
        return self.lib.usbc_step(0)

    def events(self) -> list[tuple[int, int]]:
        ev, arg = (ctypes.c_uint8 * 64)(), (ctypes.c_uint16 * 64)()
        n = self.lib.usbc_events(ev, arg, 64)
        return [(ev[i], arg[i]) for i in range(min(n, 64))]

    def event_text(self, ev: int, arg: int) -> str:
        out = ctypes.create_string_buffer(100)
        self.lib.usbc_event_text(ev, arg, out, 100)
        return out.value.decode()

    def stats(self) -> dict[str, int]:
        out = (ctypes.c_uint16 * 7)()
        self.lib.usbc_stats(out)
        keys = ("attaches", "detaches", "enum_failures", "stalls", "naks_ridden", "xfer_errors", "last_hr")
        return dict(zip(keys, out, strict=True))

    def device(self) -> dict[str, int]:
        out = (ctypes.c_uint16 * 7)()
        self.lib.usbc_device(out)
        keys = ("vid", "pid", "max_packet0", "bulk_in", "bulk_out", "in_packet", "out_packet")
        return dict(zip(keys, out, strict=True))

    def phone_strings(self) -> list[str]:
        return [self.lib.usbc_phone_string(i).decode() for i in range(6)]

    def last_error(self) -> str:
        return self.lib.usbc_last_error().decode()

    def phone_write(self, data: bytes) -> int:
        return self.lib.usbc_phone_write(_buf(data), len(data))

    def phone_read(self) -> bytes:
        out = (ctypes.c_uint8 * 65536)()
        return bytes(out[: self.lib.usbc_phone_read(out, 65536)])

    def board_write(self, data: bytes) -> int:
        return self.lib.usbc_board_write(_buf(data), len(data))

    def board_read(self) -> bytes:
        out = (ctypes.c_uint8 * 65536)()
        return bytes(out[: self.lib.usbc_board_read(out, 65536)])

    def pump(self, passes: int) -> tuple[bytes, bytes]:
        """Run `passes` main-loop passes, the board's app reading what arrives each pass: (board got,
        phone got)."""
        board, phone = bytearray(), bytearray()
        for _ in range(passes):
            self.step()
            board += self.board_read()
            phone += self.phone_read()
        return bytes(board), bytes(phone)


@pytest.fixture
def stack():
    s = Stack()
    yield s
    s.close()


def _firmware_identity() -> list[str]:
    """The five identity strings compiled into the firmware (board_gen.h), in SEND_STRING order."""
    text = (FIRMWARE_DIR / "include" / "board_gen.h").read_text()
    names = ("MANUFACTURER", "MODEL", "DESCRIPTION", "VERSION", "URI")
    found = [re.search(rf'#define IDENTITY_{n} "([^"]*)"', text) for n in names]
    assert all(found), "board_gen.h lacks an IDENTITY_* string"
    return [m.group(1) for m in found if m]


def _accessory(stack: Stack) -> None:
    assert stack.run_until(RUNNING) > 0, (stack.state, stack.events(), stack.last_error())


def test_enumerates_switches_the_phone_and_sends_the_identity_strings(stack):
    passes = stack.run_until(RUNNING)
    assert passes > 0
    assert stack.lib.usbc_phone_mode() == PHONE_ACCESSORY
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    dev = stack.device()
    assert dev["vid"] == 0x18D1 and 0x2D00 <= dev["pid"] <= 0x2D05
    assert dev["bulk_in"] and dev["bulk_out"] and dev["bulk_in"] != dev["bulk_out"]
    assert dev["in_packet"] == dev["out_packet"] == 64
    assert stack.lib.usbc_version() == 2
    assert stack.events() == [(EV_STARTED, 2), (EV_UP, dev["pid"])]
    assert stack.event_text(EV_UP, dev["pid"]) == f"USB accessory connected, product 0x{dev['pid']:x}"
    st_ = stack.stats()
    assert st_["attaches"] == 2 and st_["detaches"] == 1  # the normal-mode phone, then the accessory
    assert st_["enum_failures"] == 0
    assert stack.last_error() == ""
    # debounce (200 ms) + reset (50 ms) + recovery (20 ms), twice, plus the transfers: well under 1 s
    assert passes * PASS_US < 1_000_000


def test_an_accessory_already_in_accessory_mode_gets_no_second_handshake(stack):
    _accessory(stack)
    stack.fault("detach")
    assert stack.run_until(IDLE, 50) > 0
    stack.fault("attach")
    _accessory(stack)
    # the model's phone comes back in normal mode after a replug: the handshake runs again, strings and all
    started = [e for e in stack.events() if e[0] == EV_STARTED]
    assert len(started) == 2
    assert stack.last_error() == ""


@pytest.mark.parametrize("version", [1, 2])
def test_aoa_versions_1_and_2_are_accepted(stack, version):
    stack.fault("aoa", version)
    _accessory(stack)
    assert stack.lib.usbc_version() == version
    assert (EV_STARTED, version) in stack.events()


def test_a_phone_without_aoa_is_refused_with_a_log(stack):
    stack.fault("aoa", 0)
    assert stack.run_until(REFUSED) > 0
    assert stack.events() == [(EV_NO_AOA, 0)]
    assert stack.event_text(EV_NO_AOA, 0) == "USB device refused: no Android accessory mode (AOA protocol 0)"
    # refused for good: no strings, no START, no retry loop, while the phone stays plugged in
    assert stack.step(3000) == REFUSED
    assert stack.phone_strings() == [""] * 6
    assert stack.lib.usbc_phone_mode() == PHONE_NORMAL
    assert stack.events() == [(EV_NO_AOA, 0)]
    assert stack.last_error() == ""


def test_a_phone_that_takes_start_but_never_switches_is_refused_after_a_few_tries(stack):
    """A phone that answers GET_PROTOCOL, takes the strings and START but stays in its normal mode (no
    accessory app, or AOA barred by policy) gets START a few times, then is refused with an ERROR Log,
    not retried every 3 s for as long as it stays plugged in."""
    stack.fault("never_switch", 1)
    passes = stack.run_until(REFUSED, 2 * AOA_HANDSHAKE_TRIES * AOA_REENUM_US // PASS_US)
    assert passes > 0, (stack.state, stack.events(), stack.last_error())
    assert passes * PASS_US >= AOA_HANDSHAKE_TRIES * AOA_REENUM_US
    assert stack.events() == [(EV_STARTED, 2)] * AOA_HANDSHAKE_TRIES + [(EV_NO_SWITCH, 2)]
    assert (
        stack.event_text(EV_NO_SWITCH, 2)
        == "USB phone refused: no accessory mode after START, AOA protocol 2"
    )
    assert stack.lib.usbc_phone_mode() == PHONE_NORMAL
    # refused for good while it stays plugged in: no more START, no more events
    assert stack.step(3 * AOA_REENUM_US // PASS_US) == REFUSED
    assert len(stack.events()) == AOA_HANDSHAKE_TRIES + 1
    assert stack.last_error() == ""
    # unplugged and plugged in again, it is a new device that gets its tries again (and switches now)
    stack.fault("detach")
    assert stack.run_until(IDLE, 50) > 0
    stack.fault("never_switch", 0)
    stack.fault("attach")
    _accessory(stack)
    assert stack.events()[-2:] == [(EV_STARTED, 2), (EV_UP, stack.device()["pid"])]
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    assert stack.last_error() == ""


def test_a_nak_storm_is_ridden_out(stack):
    stack.fault("nak", 25)  # every data transaction, control and bulk, is NAKed 25 times first
    _accessory(stack)
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    payload = bytes(range(256)) * 3
    stack.phone_write(payload)
    stack.board_write(payload[::-1])
    board, phone = stack.pump(1000)  # one NAK per pass and direction: ~26 passes a packet
    assert board == payload and phone == payload[::-1]
    assert stack.stats()["naks_ridden"] > 100
    assert stack.stats()["enum_failures"] == 0
    assert stack.last_error() == ""


def test_a_stall_on_endpoint_zero_is_survived(stack):
    stack.fault("stall", 0)  # the first control transaction is STALLed once
    _accessory(stack)
    assert stack.stats()["stalls"] >= 1
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    assert stack.last_error() == ""


@pytest.mark.parametrize("direction", ["in", "out"])
def test_a_stalled_bulk_endpoint_is_cleared_and_the_stream_goes_on(stack, direction):
    _accessory(stack)
    dev = stack.device()
    first, second = b"before the stall|", b"after the stall"
    stack.phone_write(first)
    stack.board_write(first)
    board, phone = stack.pump(10)
    assert board == first and phone == first
    stack.fault("stall", dev["bulk_in"] if direction == "in" else dev["bulk_out"])
    stack.phone_write(second)
    stack.board_write(second)
    board, phone = stack.pump(50)
    assert board == second and phone == second  # nothing lost, nothing doubled
    assert stack.stats()["stalls"] == 1
    assert stack.state == RUNNING
    assert stack.last_error() == ""


def test_detach_goes_back_to_waiting_and_reattach_re_enumerates(stack):
    _accessory(stack)
    stack.phone_write(b"half a fra")
    stack.step(5)
    stack.fault("detach")
    assert stack.run_until(IDLE, 5) > 0  # seen within a few passes (the INT pin)
    assert stack.lib.usbc_host_state() == USB_DETACHED
    assert stack.events()[-1] == (EV_DOWN, 0)
    assert stack.step(2000) == IDLE  # an empty port: nothing happens, nothing spins
    stack.fault("attach")
    _accessory(stack)
    assert stack.events()[-1][0] == EV_UP
    stack.phone_write(b"fresh")
    board, _ = stack.pump(10)
    assert board.endswith(b"fresh")
    assert stack.stats()["detaches"] >= 2
    assert stack.last_error() == ""


def test_a_replug_between_two_passes_is_a_new_device(stack):
    stack.fault("aoa", 0)
    assert stack.run_until(REFUSED) > 0
    stack.fault("detach")  # out and back in before the next main-loop pass looks
    stack.fault("aoa", 2)
    stack.fault("attach")
    _accessory(stack)  # not left refusing the phone that was there before
    assert stack.stats()["detaches"] >= 1
    assert stack.last_error() == ""


def test_a_detach_in_the_middle_of_the_handshake_starts_over(stack):
    assert stack.run_until(HANDSHAKE) > 0
    stack.step(2)
    stack.fault("detach")
    stack.step(10)
    assert stack.state == IDLE
    stack.fault("attach")
    _accessory(stack)
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    assert stack.last_error() == ""


def test_a_phone_that_stops_answering_mid_handshake_is_retried_and_recovers(stack):
    assert stack.run_until(HANDSHAKE) > 0
    stack.fault("nak", 1_000_000)  # every data stage NAKed: each control transfer times out (500 ms)
    stack.step(3000)
    assert (EV_FAILED, 4) in stack.events()  # hrNAK was the last word
    assert stack.state in (IDLE, HANDSHAKE)  # never stuck refusing a phone that may come good
    assert stack.stats()["enum_failures"] >= 1
    stack.fault("nak", 0)
    _accessory(stack)
    assert stack.phone_strings() == [*_firmware_identity(), "LAB-01"]
    assert stack.last_error() == ""


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    chunks=st.lists(st.binary(min_size=1, max_size=200), min_size=1, max_size=8),
    packet=st.integers(1, 64),
    zlp=st.booleans(),
)
def test_bytes_arrive_in_order_across_packet_boundaries(chunks, packet, zlp):
    s = Stack()
    try:
        _accessory(s)
        s.fault("packet", packet)
        s.fault("zlp", 1 if zlp else 0)
        sent = b"".join(chunks)
        for c in chunks:
            assert s.phone_write(c) == len(c)
        got, _ = s.pump(len(sent) // max(packet, 1) + 40)
        assert got == sent
        # and the other way: the board's writes, 64-byte multiples included (ended by a ZLP)
        for c in chunks:
            s.board_write(c)
        _, phone = s.pump(len(sent) // 64 + 40)
        assert phone == sent
        assert s.last_error() == ""
    finally:
        s.close()


FAULT_ACTIONS = st.one_of(
    st.tuples(st.just("nak"), st.integers(0, 40)),
    st.tuples(st.just("stall"), st.integers(0, 2)),
    st.tuples(st.just("detach"), st.just(0)),
    st.tuples(st.just("attach"), st.just(0)),
    st.tuples(st.just("packet"), st.integers(1, 64)),
    st.tuples(st.just("zlp"), st.integers(0, 1)),
    st.tuples(st.just("aoa"), st.integers(0, 2)),
    st.tuples(st.just("never_switch"), st.integers(0, 1)),
    st.tuples(st.just("passes"), st.integers(1, 400)),
    st.tuples(st.just("phone"), st.integers(1, 300)),
    st.tuples(st.just("board"), st.integers(1, 300)),
)


@settings(max_examples=40, deadline=None)
@given(actions=st.lists(FAULT_ACTIONS, max_size=25))
def test_any_sequence_of_faults_leaves_a_stack_that_recovers(actions):
    """Faults, plugs and traffic in any order: the board never breaks the protocol, no pass runs long,
    and once the phone is plugged in and well again the link comes back and carries bytes exactly."""
    s = Stack()
    try:
        for name, value in actions:
            if name == "passes":
                s.pump(value)
            elif name == "phone":
                s.phone_write(bytes(range(256))[:value])
            elif name == "board":
                s.board_write(bytes(range(256))[:value])
            else:
                s.fault(name, value)
                if name == "detach":
                    s.pump(5)  # a cable is out for more than a few main-loop passes
            assert s.last_error() == ""
        for name, value in (
            ("nak", 0),
            ("packet", 64),
            ("zlp", 0),
            ("aoa", 2),
            ("never_switch", 0),
            ("detach", 0),
        ):
            s.fault(name, value)  # a healthy phone, plugged in afresh
        s.pump(5)
        s.fault("attach")
        _accessory(s)
        s.pump(300)  # what was in flight before drains (or was lost with the cable)
        payload = bytes(range(200)) * 3
        s.phone_write(payload)
        s.board_write(payload[::-1])
        board, phone = s.pump(300)
        assert board == payload and phone == payload[::-1]
        assert s.last_error() == ""
        assert s.lib.usbc_max_pass_us() < 2000
    finally:
        s.close()


def test_a_frame_across_packet_boundaries_decodes_whole(stack):
    _accessory(stack)
    stack.fault("packet", 7)
    frames = [encode_frame(Heartbeat(time_ms=i, state=1), i) for i in range(5)]
    frames.append(encode_frame(Log(severity=Severity.INFO, code=1, text="x" * 150), 5))
    wire = b"".join(frames)
    assert len(wire) > 128
    stack.phone_write(wire)
    got, _ = stack.pump(200)
    events = decode_stream(got)
    assert [e.message for e in events if isinstance(e, Frame)] == [
        *(Heartbeat(time_ms=i, state=1) for i in range(5)),
        Log(severity=Severity.INFO, code=1, text="x" * 150),
    ]


def test_board_writes_of_whole_packets_arrive_and_the_queue_empties(stack):
    _accessory(stack)
    before = stack.phone_read()
    assert before == b""
    stack.board_write(bytes(range(64)) * 2)  # two full packets, then the queue is empty: a ZLP ends it
    _, phone = stack.pump(5)
    assert phone == bytes(range(64)) * 2
    assert stack.lib.usbc_board_tx_pending() == 0
    assert stack.last_error() == ""


def test_every_pass_is_bounded(stack):
    stack.fault("nak", 50)
    _accessory(stack)
    stack.phone_write(bytes(4000))
    stack.board_write(bytes(4000))
    stack.pump(300)
    stack.fault("detach")
    stack.step(50)
    # a pass runs at most four transactions of <= 1.2 ms each by construction; with the model's
    # answers (1 us an SPI byte) a pass, full pipes and NAK storms included, takes well under 2 ms
    assert 0 < stack.lib.usbc_max_pass_us() < 2000


# ---------------------------------------------------------------------------------------------------------
# The link byte of the EEPROM configuration (firmware_sim/avr/eeprom.py -> firmware/src/config.c)


@pytest.mark.parametrize("link", eeprom.LINKS)
def test_the_configuration_block_carries_the_link(link):
    status, got, _ = config_parse(eeprom.config_block(BoardConfig(), link=link))
    assert status == 0 and got["link"] == eeprom.LINKS.index(link)


def test_uart_stays_the_default_link():
    status, got, _ = config_parse(eeprom.EepromImage(BoardConfig()).to_bytes()[: eeprom.CONFIG_SIZE])
    assert status == 0 and eeprom.LINKS[int(got["link"])] == "uart"
    _, erased, _ = config_parse(b"\xff" * eeprom.CONFIG_SIZE)  # no block: BoardConfig's defaults
    assert eeprom.LINKS[int(erased["link"])] == "uart"


def test_an_unknown_link_is_refused_by_the_image_builder_and_the_firmware():
    with pytest.raises(ConfigError, match="link"):
        eeprom.config_block(BoardConfig(), link="can")
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    body[eeprom.field_offsets()["link"]] = len(eeprom.LINKS)
    status, got, problem = config_parse(bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body))))
    assert status == 3 and got["link"] == 0  # CONFIG_INVALID: the defaults, UART
    assert problem == 21  # config.c's BAD_LINK: the last of its problems ("link")


def test_the_image_cli_writes_the_link(tmp_path):
    out = tmp_path / "board.eep"
    assert eeprom.main(["--out", str(out), "--link", "first"]) == 0
    _, got, _ = config_parse(out.read_bytes()[: eeprom.CONFIG_SIZE])
    assert eeprom.LINKS[int(got["link"])] == "first"

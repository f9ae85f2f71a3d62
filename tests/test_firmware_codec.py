"""The firmware's protocol codec (firmware/src: wire.c, frame.c, cobs.c, crc16.c and the generated tables).

On the ATmega2560 (simavr): every frame of fixtures/protocol_vectors.json goes through the codec-check
firmware, which decodes it and re-encodes the decoded message (a canonical vector must come back byte for
byte), and every bad frame must be refused for the expected reason; the streams give the expected events.
On the host (the same C sources through ctypes): random messages, random noisy streams in random chunks,
compared event by event and counter by counter with protocol.frame.Deframer.
"""

from __future__ import annotations

import json
import random

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_protocol_strategies import numbered_stream, wire_frames

from firmware_sim.avr import CODEC_CHECK_ELF, AvrBoard, HarnessOptions
from firmware_sim.avr.hostlib import CDeframer, CFrame, cobs_decode, cobs_encode, crc16
from hil.scenario.paths import FIXTURES
from protocol import cobs
from protocol.crc import crc16_ccitt_false
from protocol.frame import BadFrameReason, Deframer, Frame, encode_frame
from protocol.messages import Heartbeat, Hello

pytestmark = pytest.mark.firmware  # the C firmware built by make -C firmware (tests/conftest.py)

VECTORS = json.loads((FIXTURES / "protocol_vectors.json").read_text())
FRAMES = {v["name"]: v for v in VECTORS["frames"]}
REASONS = tuple(BadFrameReason)


class CodecCheck:
    """The codec-check firmware on simavr, unpaced, behind its pty."""

    def __init__(self) -> None:
        import serial

        self.board = AvrBoard(options=HarnessOptions(elf=CODEC_CHECK_ELF, paced=False))
        self.port = serial.Serial(self.board.port, timeout=5.0)
        probe = bytes.fromhex(VECTORS["frames"][0]["wire_hex"])
        for _ in range(50):  # bytes sent before the firmware enables its receiver are lost, as on a board
            self.port.write(probe)
            self.port.timeout = 0.2
            if self.port.read_until(b"\x00") == probe:
                break
        else:
            raise AssertionError("the codec-check firmware never answered")
        self.port.timeout = 5.0

    def reply(self) -> bytes | tuple[BadFrameReason, int, int]:
        """The next answer: the re-encoded frame, or (reason, field, element) of a bad one."""
        raw = self.port.read_until(b"\x00")
        assert raw.endswith(b"\x00"), f"no answer from the firmware (got {raw!r})"
        body = cobs.decode(raw[:-1])
        if body[:1] == b"\xba" and len(body) == 4:
            return REASONS[body[1] - 1], body[2], body[3]
        return raw

    def close(self) -> None:
        self.port.close()
        self.board.check()
        self.board.close()


@pytest.fixture(scope="module")
def avr_codec():
    check = CodecCheck()
    yield check
    check.close()


def test_every_canonical_frame_round_trips_through_the_avr_codec(avr_codec):
    for vector in VECTORS["frames"]:
        wire = bytes.fromhex(vector["wire_hex"])
        avr_codec.port.write(wire)
        assert avr_codec.reply() == wire, vector["name"]


def test_every_bad_frame_is_refused_by_the_avr_codec_for_its_reason(avr_codec):
    for vector in VECTORS["bad_frames"]:
        avr_codec.port.write(bytes.fromhex(vector["wire_hex"]))
        answer = avr_codec.reply()
        assert isinstance(answer, tuple), f"{vector['name']}: accepted"
        assert answer[0] == BadFrameReason(vector["reason"]), vector["name"]


def test_streams_give_the_expected_events_on_the_avr(avr_codec):
    for stream in VECTORS["streams"]:
        avr_codec.port.write(bytes.fromhex(stream["wire_hex"]))
        for event in stream["events"]:
            answer = avr_codec.reply()
            if "frame" in event:
                assert answer == bytes.fromhex(FRAMES[event["frame"]]["wire_hex"]), stream["name"]
            else:
                assert isinstance(answer, tuple) and answer[0] == BadFrameReason(event["bad"]), stream["name"]


# --------------------------------------------------------------------------- host build, same sources
def test_cobs_and_crc_vectors_on_the_host_build():
    for v in VECTORS["cobs"]:
        decoded, encoded = bytes.fromhex(v["decoded_hex"]), bytes.fromhex(v["encoded_hex"])
        assert cobs_encode(decoded) == encoded
        assert cobs_decode(encoded) == decoded
    for v in VECTORS["crc"]:
        assert crc16(bytes.fromhex(v["data_hex"])) == int(v["crc"], 16)
    assert cobs_decode(b"\x05\x01") is None  # a group running past the end


@settings(max_examples=500, deadline=None)
@given(data=st.binary(max_size=600), start=st.integers(0, 0xFFFF), cut=st.integers(0, 600))
def test_the_firmware_crc_is_the_reference_crc_in_any_pieces(data: bytes, start: int, cut: int):
    """crc16.c's byte-at-a-time CRC (three shifts of a byte, no table) against protocol.crc's, from any
    value and fed in two pieces, as the firmware feeds it (a set's CRC over its header and knots)."""
    whole = crc16(data, start)
    assert whole == crc16_ccitt_false(data, start)
    assert crc16(data[cut:], crc16(data[:cut], start)) == whole


def _python_events(events) -> list[bytes | BadFrameReason]:
    return [
        encode_frame(e.message, e.seq, int(e.flags)) if isinstance(e, Frame) else e.reason for e in events
    ]


def _c_events(events) -> list[bytes | BadFrameReason]:
    return [e.wire if isinstance(e, CFrame) else e for e in events]


@settings(max_examples=300, deadline=None)
@given(frame=wire_frames())
def test_random_frames_decode_and_reencode_identically(frame):
    message, seq, flags, wire = frame
    (event,) = CDeframer().feed(wire)
    assert isinstance(event, CFrame)
    assert (event.msg_id, event.seq, event.flags) == (message.MSG_ID, seq, flags)
    assert event.wire == wire


def _board_deframer() -> Deframer:
    """The Python deframer as a board keeps it: a ``Hello`` begins the host's numbering afresh (the step to
    it no gap, no duplicate), as the firmware's ``deframer_feed`` does."""
    return Deframer(renumbered_by=(Hello.MSG_ID,))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(0, 255)), min_size=1, max_size=40))
def test_a_hello_at_any_number_is_counted_as_the_boards_python_deframer_counts_it(numbered):
    """Frames numbered anyhow (a restarted host's Hello at 0, a repeat, a jump), Hellos among them: the C
    and the Python board's counters agree; a Hello never adds to the gaps or the duplicates."""
    hello = Hello(schema_hash=1, manufacturer="t", model="m", serial="s")
    wire = b"".join(encode_frame(hello if is_hello else Heartbeat(), seq) for is_hello, seq in numbered)
    c, py = CDeframer(), _board_deframer()
    assert _c_events(c.feed(wire)) == _python_events(py.feed(wire))
    _compare_counters(c, py)
    counted = [
        (numbered[i][1] - numbered[i - 1][1]) & 0xFF for i in range(1, len(numbered)) if not numbered[i][0]
    ]
    assert py.counters.seq_gaps == sum(step - 1 for step in counted if step > 1)
    assert py.counters.duplicates == sum(1 for step in counted if step == 0)


def _compare_counters(c: CDeframer, py: Deframer) -> None:
    got, want = c.counters(), py.counters
    assert (
        got["frames"],
        got["bad_total"],
        got["resyncs"],
        got["seq_gaps"],
        got["duplicates"],
        got["bytes"],
    ) == (want.frames, want.bad_total, want.resyncs, want.seq_gaps, want.duplicates, want.bytes)
    assert got["bad"] == {r: n for r, n in want.bad.items() if n}


@settings(max_examples=150, deadline=None)
@given(
    stream=numbered_stream(),
    noise=st.lists(st.tuples(st.integers(0, 10_000), st.binary(min_size=1, max_size=300)), max_size=4),
    flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)), max_size=6),
    seed=st.integers(0, 2**32 - 1),
)
def test_noisy_streams_in_random_chunks_give_the_same_events_and_counters(stream, noise, flips, seed):
    data = bytearray(b"".join(wire for _, wire in stream))
    for at, junk in noise:
        data[at % (len(data) + 1) : at % (len(data) + 1)] = junk
    for at, mask in flips:
        if data:
            data[at % len(data)] ^= mask
    rng = random.Random(seed)
    c, py = CDeframer(), _board_deframer()
    got, want = [], []
    i = 0
    while i < len(data):
        n = rng.randint(1, 64)
        got += _c_events(c.feed(bytes(data[i : i + n])))
        want += _python_events(py.feed(bytes(data[i : i + n])))
        i += n
    assert got == want
    _compare_counters(c, py)


def test_a_megabyte_without_delimiters_is_one_resync_per_overlong_run_and_the_next_frame_decodes():
    wire = bytes.fromhex(VECTORS["frames"][0]["wire_hex"])
    garbage = random.Random(1).randbytes(1 << 20).replace(b"\x00", b"\x01")
    c, py = CDeframer(), _board_deframer()
    got = _c_events(c.feed(garbage + b"\x00" + wire))
    want = _python_events(py.feed(garbage + b"\x00" + wire))
    assert got == want and got[-1] == wire and got.count(BadFrameReason.TOO_LONG) >= 1
    _compare_counters(c, py)

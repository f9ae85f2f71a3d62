"""The binary calibration set and its CALIBRATION transfer: byte round trips, damage always rejected with a
location, fragments through real frames (lost, repeated, reordered, noisy link) back to the same set, and
an upload of a fitted set to the emulated board."""

from __future__ import annotations

import json
import random
import struct

import pytest
from conformance.host import lockstep
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import Bundle, RuleBasedStateMachine, invariant, rule
from test_calibration_strategies import unit_calibrations

from hil.calibration.files import load_calibration
from hil.scenario.paths import FIXTURES
from protocol.calibration import (
    MAX_TRANSFER_BYTES,
    Reassembler,
    UnitCalibration,
    default_unit_calibration,
    fragment,
    reassemble,
)
from protocol.calibration.codec import CRC, HEADER, KNOT, MAX_SIZE
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError, FieldRangeError
from protocol.frame import Deframer, Frame, encode_frame
from protocol.messages import (
    MAX_CALIBRATION_CHUNK,
    Ack,
    ActuatorSetpoint,
    Arm,
    CalibrationData,
    CalibrationRequest,
    GimbalMode,
    Telemetry,
    UnitSetpoint,
)

SETTINGS = settings(max_examples=40, deadline=None)
VECTORS = json.loads((FIXTURES / "calibration" / "vectors.json").read_text())


# ------------------------------------------------------------------------- bytes
@SETTINGS
@given(unit_calibrations())
def test_to_bytes_from_bytes_round_trip(cal):
    data = cal.to_bytes()
    n = len(cal.rotor.curve.x) + len(cal.gimbal_rate.lower.x) + len(cal.gimbal_rate.upper.x)
    n += len(cal.gimbal_angle.curve.x)
    assert len(data) == HEADER.size + KNOT.size * n + CRC.size <= MAX_SIZE
    assert struct.unpack_from("<H", data, len(data) - 2)[0] == crc16_ccitt_false(data[:-2])
    back = UnitCalibration.from_bytes(data)
    assert back == cal and back.to_bytes() == data


def test_default_set_layout_is_the_documented_one():
    data = default_unit_calibration().to_bytes()
    assert data[:4] == b"VC\x01\x00"
    low, high, dead, kv, hold = struct.unpack_from("<5f", data, 4)
    assert (low, high, dead, kv, hold) == (1000.0, 2000.0, 40.0, 50.0, 1500.0)
    assert tuple(data[24:28]) == (11, 6, 6, 9)
    x, y, m = struct.unpack_from("<3f", data, 28)  # first knot of the throttle curve
    assert (x, y) == (0.0, 0.0) and m > 0
    assert len(data) == 28 + 12 * 32 + 2 == 414


@SETTINGS
@given(unit_calibrations(), st.data())
def test_any_damaged_byte_is_rejected_with_a_location(cal, data):
    good = cal.to_bytes()
    i = data.draw(st.integers(0, len(good) - 1))
    b = data.draw(st.integers(0, 255).filter(lambda v: v != good[i]))
    bad = good[:i] + bytes([b]) + good[i + 1 :]
    with pytest.raises(CalibrationError, match=r"^upload unit 2: "):
        UnitCalibration.from_bytes(bad, source="upload unit 2")


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=700))
def test_arbitrary_bytes_only_ever_raise_calibration_error(blob):
    with pytest.raises(CalibrationError):
        UnitCalibration.from_bytes(blob, source="fuzz")


@pytest.mark.parametrize("case", VECTORS["malformed"], ids=lambda c: c["what"])
def test_malformed_vector_sets_are_rejected_where_the_vectors_say(case):
    with pytest.raises(CalibrationError) as info:
        UnitCalibration.from_bytes(bytes.fromhex(case["hex"]), source="vector")
    assert case["where"] in str(info.value)
    assert str(info.value).startswith("vector")


# ------------------------------------------------------------------------- fragments
@pytest.mark.parametrize("size", [0, 1, 199, 200, 201, 414, 600, MAX_TRANSFER_BYTES])
def test_fragment_sizes_and_headers(size):
    data = bytes(random.Random(size).getrandbits(8) for _ in range(size))
    parts = fragment(3, 77, data)
    assert len(parts) == max(1, -(-size // MAX_CALIBRATION_CHUNK))
    assert all(len(p.chunk) == MAX_CALIBRATION_CHUNK for p in parts[:-1])
    assert b"".join(p.chunk for p in parts) == data
    assert {(p.unit, p.transfer_id, p.count, p.total_len, p.set_crc) for p in parts} == {
        (3, 77, len(parts), size, crc16_ccitt_false(data))
    }
    assert [p.index for p in parts] == list(range(len(parts)))
    assert reassemble(list(reversed(parts))) == (3, data)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        ((8, 1, b"x"), "unit"),
        ((0, 256, b"x"), "transfer_id"),
        ((0, 1, b"x" * (MAX_TRANSFER_BYTES + 1)), "total_len"),
    ],
)
def test_fragment_refuses_what_the_message_cannot_carry(args, field):
    with pytest.raises(FieldRangeError, match=field):
        fragment(*args)


def _parts(unit=0, tid=1, size=450):
    return fragment(unit, tid, bytes(range(256)) * (size // 256) + bytes(size % 256))


def test_reassembler_tolerates_duplicates_and_reports_progress():
    parts = _parts()
    r = Reassembler()
    assert r.feed(parts[0]) is None and r.in_progress == (0, 1)
    assert r.feed(parts[0]) is None  # a retry after a lost ACK
    assert r.feed(parts[2]) is None
    unit, data = r.feed(parts[1])
    assert (unit, data) == (0, b"".join(p.chunk for p in parts))
    assert r.in_progress is None
    for p in parts:  # late retries of the finished transfer do not start (or finish) it again
        assert r.feed(p) is None
    c = r.counters
    assert (c.fragments, c.duplicates, c.completed, c.failed, c.restarts) == (7, 4, 1, 0, 0)


def test_a_new_transfer_abandons_the_unfinished_one():
    r = Reassembler()
    old, new = _parts(tid=1), _parts(tid=2, size=300)
    r.feed(old[0])
    r.feed(old[1])
    assert r.feed(new[0]) is None and r.in_progress == (0, 2)
    assert r.feed(old[2]) is None and r.in_progress == (0, 1)  # the stale one restarts (and never completes)
    assert r.feed(new[0]) is None and r.feed(new[1])[1] == b"".join(p.chunk for p in new)
    assert r.counters.restarts == 3


def _with(part: CalibrationData, **changes) -> CalibrationData:
    fields = {
        f: getattr(part, f)
        for f in ("unit", "transfer_id", "index", "count", "total_len", "set_crc", "chunk")
    }
    return CalibrationData(**{**fields, **changes})


@pytest.mark.parametrize(
    ("damage", "phrase"),
    [
        (lambda p: [p[0], _with(p[1], set_crc=p[1].set_crc ^ 1)], "contradicts"),
        (lambda p: [p[0], _with(p[0], chunk=b"\x01" + p[0].chunk[1:])], "different bytes"),
        (lambda p: [_with(p[0], count=2)], "does not fit total_len"),
        (lambda p: [_with(p[2], index=3)], "not below count"),
        (lambda p: [_with(p[0], chunk=p[0].chunk[:-1])], "chunk of 199 bytes"),
        (lambda p: [p[0], _with(p[2], total_len=449, chunk=p[2].chunk[:-1])], "contradicts"),
    ],
)
def test_inconsistent_fragments_are_refused_naming_the_fragment(damage, phrase):
    parts = _parts(unit=1, tid=9)
    r = Reassembler()
    with pytest.raises(CalibrationError) as info:
        for p in damage(parts):
            r.feed(p)
    assert phrase in str(info.value)
    assert "calibration transfer 9 (unit 1), fragment" in str(info.value)
    assert r.in_progress is None and r.counters.failed == 1
    assert reassemble(parts)[0] == 1  # a clean transfer still works afterwards


def test_a_set_whose_crc_does_not_match_is_refused():
    parts = [_with(p, set_crc=0x1234) for p in _parts()]
    r = Reassembler()
    r.feed(parts[0])
    r.feed(parts[1])
    with pytest.raises(CalibrationError, match="announced 450 bytes with CRC 0x1234"):
        r.feed(parts[2])


def test_memory_is_bounded_by_max_len():
    r = Reassembler(max_len=600)
    with pytest.raises(CalibrationError, match="exceeds this receiver's 600 bytes"):
        r.feed(_parts(size=601)[0])


# ------------------------------------------------------------------------- through real frames
@SETTINGS
@given(unit_calibrations(), st.integers(0, 2**32 - 1), st.integers(0, 255))
def test_calibration_message_round_trip_over_a_lossy_noisy_link(cal, seed, transfer_id):
    """fragment → encode_frame → (loss, repeats, reordering, noise, random chunking) → Deframer →
    Reassembler → from_bytes gives the same set."""
    rng = random.Random(seed)
    data = cal.to_bytes()
    parts = fragment(5, transfer_id, data)
    sends = [i for i in range(len(parts)) for _ in range(rng.randint(1, 3))]  # retries repeat fragments
    rng.shuffle(sends)
    lost = {rng.randrange(len(sends)) for _ in range(rng.randint(0, 2))}
    resent = [i for k, i in enumerate(sends) if k in lost]  # a lost fragment is retried until acknowledged
    stream = bytearray()
    for seq, i in enumerate([i for k, i in enumerate(sends) if k not in lost] + resent):
        stream += bytes(rng.getrandbits(8) | 1 for _ in range(rng.randint(0, 5))) + b"\x00"  # line noise
        stream += encode_frame(parts[i], seq % 256)
    deframer, r, done = Deframer(), Reassembler(), []
    pos = 0
    while pos < len(stream):
        step = rng.randint(1, 64)
        for ev in deframer.feed(bytes(stream[pos : pos + step])):
            if isinstance(ev, Frame):
                out = r.feed(ev.message)
                if out is not None:
                    done.append(out)
        pos += step
    assert done == [(5, data)]
    assert UnitCalibration.from_bytes(done[0][1]) == cal


# ------------------------------------------------------------------------- the emulated board
def test_a_fitted_set_uploaded_to_the_board_drives_its_outputs_and_downloads_unchanged():
    mirrored = load_calibration(FIXTURES / "calibration" / "pyramid4.toml").unit(3).calibration
    assert not mirrored.gimbal_rate.upper.rising  # unit 3's servo is mounted mirrored
    board, clock, host = lockstep()
    host.handshake()
    for part in fragment(0, 42, mirrored.to_bytes()):
        assert isinstance(host.request(part), Ack)
    assert board.calibrations[0] == mirrored
    assert isinstance(host.request(Arm()), Ack)
    sp = ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.5, 300.0),) * 4)
    host.keepalive = lambda: sp
    host.poll(0.3)
    tel = host.wait_type(Telemetry, 0.1)
    want = round(mirrored.gimbal_pulse_us(0.5, GimbalMode.RATE).value)
    assert tel.pulses_us[0] == want < 1500  # positive rate: a shorter pulse on the mirrored servo
    assert (
        tel.pulses_us[2]
        == round(default_unit_calibration().gimbal_pulse_us(0.5, GimbalMode.RATE).value)
        > 1500
    )
    host.keepalive = None
    assert isinstance(host.request(CalibrationRequest(unit=0, transfer_id=43)), Ack)
    r, got = Reassembler(), None
    end = host.now() + 1.0
    while got is None and host.now() < end:
        for ev in host.deframer.feed(host._read(0.01)):
            if isinstance(ev.message, CalibrationData):
                host.send(Ack(msg_id=CalibrationData.MSG_ID, seq=ev.seq))
                got = r.feed(ev.message) or got
    assert got == (0, mirrored.to_bytes())


# ------------------------------------------------------------------------- the Reassembler against a model
class ReassemblerModel(RuleBasedStateMachine):
    """Fragments of several transfers (some sharing a key with different contents) fed in any order, with
    repeats; the real Reassembler and a plain model must agree on every answer."""

    transfers = Bundle("transfers")

    def __init__(self) -> None:
        super().__init__()
        self.r = Reassembler(max_len=1000)
        self.key: tuple[int, int] | None = None  # model of the transfer in progress
        self.header: tuple | None = None
        self.chunks: dict[int, bytes] = {}
        self.done: tuple | None = None

    @rule(target=transfers, unit=st.integers(0, 2), tid=st.integers(0, 2), size=st.integers(0, 650))
    def new_transfer(self, unit, tid, size):
        data = bytes(random.Random(size * 7 + unit).getrandbits(8) for _ in range(size))
        return fragment(unit, tid, data)

    @rule(parts=transfers, pick=st.integers(0, 3))
    def feed(self, parts, pick):
        msg = parts[pick % len(parts)]
        header = (msg.unit, msg.transfer_id, msg.count, msg.total_len, msg.set_crc)
        expected, error = self._model(msg, header)
        if error:
            with pytest.raises(CalibrationError):
                self.r.feed(msg)
        else:
            assert self.r.feed(msg) == expected

    def _model(self, msg, header):
        if header == self.done:
            return None, False
        if self.key != (msg.unit, msg.transfer_id):
            self.key, self.header, self.chunks, self.done = (msg.unit, msg.transfer_id), header, {}, None
        elif header != self.header:
            self.key, self.header, self.chunks = None, None, {}
            return None, True
        if msg.index in self.chunks:
            return None, False
        self.chunks[msg.index] = msg.chunk
        if len(self.chunks) < msg.count:
            return None, False
        data = b"".join(self.chunks[i] for i in range(msg.count))
        self.key, self.header, self.chunks, self.done = None, None, {}, header
        return (msg.unit, data), False

    @invariant()
    def same_progress(self):
        assert self.r.in_progress == self.key
        assert sum(len(c) for c in self.r._chunks.values()) <= self.r.max_len  # bounded memory


ReassemblerModel.TestCase.settings = settings(max_examples=60, stateful_step_count=30, deadline=None)
TestReassemblerModel = ReassemblerModel.TestCase

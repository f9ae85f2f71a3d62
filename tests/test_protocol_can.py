"""The CAN mapping: real frames on a python-can virtual bus, and segmentation / reassembly under loss,
reordering and duplication (Hypothesis)."""

from __future__ import annotations

import itertools
import random
import uuid

import can
import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_protocol_strategies import extreme_message, messages, numbered_stream, wire_frames

from protocol.can import (
    FD_LENGTHS,
    MAX_WIRE,
    PRIORITY,
    CanFrame,
    CanId,
    CanReassembler,
    CanSegmenter,
    Direction,
    Priority,
    max_segments,
)
from protocol.errors import ConfigError, ProtocolError
from protocol.frame import Deframer, Frame, Framer, encode_frame
from protocol.messages import (
    CATALOGUE,
    MAX_UNITS,
    Ack,
    ActuatorSetpoint,
    Arm,
    ControlMode,
    Disarm,
    Heartbeat,
    HelloReply,
    Log,
    SetMode,
    Telemetry,
    UnitSetpoint,
    UnitState,
)

NODE = 5


# =========================================================================== a real virtual bus
@pytest.fixture
def bus_pair():
    """Two python-can virtual buses on a private channel, shut down afterwards."""
    channel = f"vscmg-{uuid.uuid4().hex[:8]}"
    a = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    b = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield a, b
    a.shutdown()
    b.shutdown()


def _send(bus: can.BusABC, frames: list[CanFrame]) -> None:
    for f in frames:
        bus.send(
            can.Message(arbitration_id=f.arbitration_id, data=f.data, is_fd=f.is_fd, is_extended_id=False)
        )


def _receive_all(bus: can.BusABC, reassembler: CanReassembler, deframer: Deframer) -> list:
    events = []
    while (msg := bus.recv(timeout=0.05)) is not None:
        events += deframer.feed(reassembler.feed_message(msg))
    return events


@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_frames_cross_a_virtual_bus_both_ways(bus_pair, fd):
    host_bus, board_bus = bus_pair
    host_out = CanSegmenter(NODE, Direction.TO_BOARD, fd=fd)
    board_out = CanSegmenter(NODE, Direction.TO_HOST, fd=fd)
    board_in = CanReassembler(NODE, Direction.TO_BOARD)
    host_in = CanReassembler(NODE, Direction.TO_HOST)
    host_framer, board_framer = Framer(), Framer()
    to_board = [
        Arm(),
        ActuatorSetpoint(units=tuple(UnitSetpoint(0.25 * i, 100.0 * i) for i in range(4))),
        Heartbeat(time_ms=99),
    ]
    to_host = [
        Ack(msg_id=Arm.MSG_ID, seq=0),
        Telemetry(time_ms=5, pulses_us=(1500,) * 8, units=(UnitState(0.125, -0.5, 300.0),) * 4),
        extreme_message(HelloReply, largest=True),  # the longest frame
        Log(text="state DISARMED -> ARMED"),
    ]
    for msg in to_board:
        _send(host_bus, host_out.segment(host_framer.encode(msg)[1]))
    for msg in to_host:
        _send(board_bus, board_out.segment(board_framer.encode(msg)[1]))
    got_board = _receive_all(board_bus, board_in, Deframer())
    got_host = _receive_all(host_bus, host_in, Deframer())
    assert [e.message for e in got_board] == to_board
    assert [e.message for e in got_host] == to_host
    assert board_in.stats.frames == len(to_board) and board_in.stats.incomplete == 0
    assert host_in.stats.malformed == host_in.stats.ignored == 0


def test_a_board_ignores_other_nodes_and_its_own_direction(bus_pair):
    a, b = bus_pair
    wire = encode_frame(Disarm(), 1)
    _send(a, CanSegmenter(NODE + 1, Direction.TO_BOARD).segment(wire))  # another board's command
    _send(a, CanSegmenter(NODE, Direction.TO_HOST).segment(wire))  # the wrong direction
    a.send(can.Message(arbitration_id=0x1ABCDEF, data=b"\x00\x01", is_extended_id=True))
    a.send(can.Message(arbitration_id=0x7FF, data=b"\x00\x01", is_extended_id=False))  # priority 7: unused
    board = CanReassembler(NODE, Direction.TO_BOARD)
    assert _receive_all(b, board, Deframer()) == []
    assert board.stats.ignored == 2 + 2 + 2 and board.stats.frames == 0


# =========================================================================== the identifier scheme
def test_arbitration_ids_order_commands_before_setpoints_before_status():
    seg = CanSegmenter(NODE, Direction.TO_BOARD)
    ids = {cls: seg.arbitration_id(cls.MSG_ID) for cls in CATALOGUE}
    assert ids[Disarm] < ids[ActuatorSetpoint] < ids[Heartbeat] < ids[Telemetry] < ids[Log]
    assert set(PRIORITY) == {cls.MSG_ID for cls in CATALOGUE}  # every message has a class
    assert seg.arbitration_id(0x7E) >> 8 == Priority.OTHER
    for value in range(0x700):
        assert CanId.parse(value).value == value
    with pytest.raises(ProtocolError):
        CanId.parse(0x700)
    assert CanId(Priority.CONTROL, Direction.TO_HOST, 127).value == 0x1FF


def test_host_and_board_never_share_an_identifier():
    for node, (cls_a, cls_b) in itertools.product((0, 5, 127), itertools.product(CATALOGUE, repeat=2)):
        host = CanSegmenter(node, Direction.TO_BOARD).arbitration_id(cls_a.MSG_ID)
        board = CanSegmenter(node, Direction.TO_HOST).arbitration_id(cls_b.MSG_ID)
        assert host != board


@pytest.mark.parametrize("fd", [False, True])
def test_segment_layout(fd):
    longest = encode_frame(extreme_message(HelloReply, largest=True), 0)
    assert len(longest) == 253  # the longest frame of the catalogue
    frames = CanSegmenter(NODE, Direction.TO_HOST, fd=fd).segment(longest)
    limit = 64 if fd else 8
    assert all(len(f.data) <= limit and f.is_fd == fd for f in frames)
    assert all(len(f.data) == limit for f in frames[:-1])  # every segment but the last is full
    if fd:
        assert all(len(f.data) in FD_LENGTHS for f in frames)
    assert [f.data[0] & 0x3F for f in frames] == list(range(len(frames)))
    assert len({f.data[0] >> 6 for f in frames}) == 1  # one transfer id
    assert b"".join(f.data[1:] for f in frames).rstrip(b"\x00") + b"\x00" == longest
    assert max_segments(False) == 37 and max_segments(True) == 5 and MAX_WIRE == 259
    setpoint = encode_frame(ActuatorSetpoint(units=(UnitSetpoint(),) * 4), 0)
    assert len(CanSegmenter(NODE, Direction.TO_BOARD, fd=fd).segment(setpoint)) == (1 if fd else 6)


def test_transfer_ids_advance_per_arbitration_id():
    seg = CanSegmenter(NODE, Direction.TO_BOARD)
    tids = [seg.segment(encode_frame(Heartbeat(), i))[0].data[0] >> 6 for i in range(6)]
    assert tids == [0, 1, 2, 3, 0, 1]
    assert seg.segment(encode_frame(Arm(), 0))[0].data[0] >> 6 == 0  # another id, its own counter


def test_segmenter_refuses_what_is_not_one_wire_frame():
    seg = CanSegmenter(NODE, Direction.TO_BOARD)
    wire = encode_frame(Arm(), 0)
    for bad in (b"", b"\x00", wire[:-1], wire + wire, b"\x01" * 300 + b"\x00"):
        with pytest.raises(ProtocolError):
            seg.segment(bad)
    with pytest.raises(ConfigError):
        CanSegmenter(128, Direction.TO_BOARD)
    with pytest.raises(ConfigError):
        CanReassembler(window=0)


# =========================================================================== reassembly (Hypothesis)
@given(wire_frames(), st.booleans(), st.randoms(use_true_random=False))
def test_any_frame_survives_segmentation_in_any_order(frame, fd, rnd):
    wire = frame[3]
    segments = CanSegmenter(NODE, Direction.TO_HOST, fd=fd).segment(wire)
    rnd.shuffle(segments)  # reordered within the frame
    rx = CanReassembler()
    out = b"".join(rx.feed(s.arbitration_id, s.data, s.is_fd) for s in segments)
    assert out == wire
    assert (rx.stats.frames, rx.stats.incomplete, rx.partial_frames) == (1, 0, 0)


def _segmented(stream, fd, node=NODE):
    seg = CanSegmenter(node, Direction.TO_BOARD, fd=fd)
    return [(i, s) for i, (_, wire) in enumerate(stream) for s in seg.segment(wire)]


def _stream_index(stream, event) -> int:
    """Which frame of ``stream`` (``[(message, wire), ...]``) a delivered event is: the one with its seq
    (a stream of at most 256 frames from one Framer numbers them uniquely) and its message."""
    found = [i for i, (m, wire) in enumerate(stream) if Deframer().feed(wire)[0].seq == event.seq]
    assert len(found) == 1 and stream[found[0]][0] == event.message
    return found[0]


@settings(max_examples=80)
@given(numbered_stream(max_frames=16), st.booleans(), st.data())
def test_lost_segments_cost_exactly_the_frames_they_belong_to(stream, fd, data):
    tagged = _segmented(stream, fd)
    lost = set(data.draw(st.lists(st.integers(0, len(tagged) - 1), unique=True, max_size=len(tagged) // 2)))
    rx = CanReassembler(NODE, Direction.TO_BOARD)
    deframer = Deframer()
    events = []
    for k, (_, s) in enumerate(tagged):
        if k not in lost:
            events += deframer.feed(rx.feed(s.arbitration_id, s.data, s.is_fd))
    damaged = {tagged[k][0] for k in lost}
    # Complete frames only, never a half-built one (each event is a Frame: its CRC held), each frame once,
    # in order on its arbitration id: every undamaged frame; a damaged one only where the 2-bit transfer
    # id wrapped over frames lost whole and the frame four ids on supplied a segment byte-identical to
    # the one it lost (a last segment holding only the delimiter) — then it is that very frame, intact.
    index = [_stream_index(stream, e) for e in events]
    undamaged = {i for i in range(len(stream)) if i not in damaged}
    extras = set(index) - undamaged
    assert undamaged <= set(index) and extras <= damaged and len(set(index)) == len(index)
    arbitration = {i: s.arbitration_id for i, s in tagged}
    for arb in set(arbitration.values()):
        on_id = [i for i in index if arbitration[i] == arb]
        assert on_id == sorted(on_id)
    assert rx.stats.frames == len(index)
    rx.reset()  # end of the run: partial frames still held are discarded too (counted as cut)
    started = {i for k, (i, _) in enumerate(tagged) if k not in lost}
    # Each damaged frame that started is discarded once, or its lone segment taken for a repeat of the
    # identical segment before it; except where the transfer id wrapped over frames lost whole and two
    # damaged frames joined: a splice (caught by the CRC) or an intact frame delivered, for both.
    c = rx.stats
    if c.spliced or extras:
        assert c.incomplete + c.cut + c.duplicates + c.spliced + 2 * len(extras) <= len(damaged & started)
    else:
        assert c.incomplete + c.cut + c.duplicates == len(damaged & started)


@settings(max_examples=80)
@given(numbered_stream(max_frames=12), st.booleans(), st.data())
def test_reordered_and_duplicated_segments_never_produce_a_corrupt_frame(stream, fd, data):
    tagged = _segmented(stream, fd)
    order = list(range(len(tagged)))
    for _ in range(data.draw(st.integers(0, 3 * len(order)))):  # local swaps: segments overtaking
        k = data.draw(st.integers(0, len(order) - 2)) if len(order) > 1 else 0
        if len(order) > 1:
            order[k], order[k + 1] = order[k + 1], order[k]
    dups = data.draw(st.lists(st.integers(0, len(order) - 1), max_size=5))
    for k in dups:
        order.insert(min(k + data.draw(st.integers(0, 3)), len(order)), order[k])
    rx = CanReassembler(NODE, Direction.TO_BOARD)
    deframer = Deframer()
    events = []
    for k in order:
        s = tagged[k][1]
        events += deframer.feed(rx.feed(s.arbitration_id, s.data, s.is_fd))
    originals = [m for m, _ in stream]
    assert all(isinstance(e, Frame) for e in events)  # no reassembly ever fails its CRC
    delivered = [e.message for e in events]
    assert all(m in originals for m in delivered)
    streams = {s.arbitration_id for _, s in tagged}  # one stream per arbitration id (its priority)
    assert rx.partial_frames <= rx.window * len(streams)
    # Within one frame any order is fine: if no segment crossed a frame boundary, nothing is lost.
    frames_in_order = [tagged[k][0] for k in order]
    if all(a <= b for a, b in zip(frames_in_order, frames_in_order[1:], strict=False)):
        assert delivered == originals


def test_a_frame_given_up_never_completes_later_from_a_newer_frames_identical_segment():
    """Arm (transfer id 0) loses its last segment; SetMode (id 1) is heard; the frames with ids 2 and 3 are
    lost whole, and the next frame under id 0 — a Disarm, whose last segment, like the Arm's, holds only
    the delimiter — loses its first. The Arm must not be completed by the Disarm's last segment and
    delivered after the newer SetMode: once another transfer id is heard, the Arm is over."""
    framer, seg = Framer(), CanSegmenter(NODE, Direction.TO_BOARD)
    arm, setmode, lost1, lost2, disarm = (
        seg.segment(framer.encode(m)[1])
        for m in (Arm(), SetMode(mode=ControlMode.SETPOINT), Arm(), Arm(), Disarm())
    )
    assert arm[-1].data[1:] == disarm[-1].data[1:] == b"\x00"  # the byte-identical last segments
    rx = CanReassembler(NODE, Direction.TO_BOARD)
    heard = [arm[0], *setmode[1:], disarm[-1]]  # everything else lost
    out = b"".join(rx.feed(f.arbitration_id, f.data) for f in heard)
    assert out == b"" and rx.stats.frames == 0
    assert rx.stats.incomplete == 2 and rx.partial_frames == 1  # the Arm, the SetMode; the Disarm waits


def test_a_reset_cuts_the_partial_frames_in_flight_and_counts_them_apart_from_losses():
    """A receiver reset as its connection closes, the peer mid-frame (a board streaming telemetry): the
    partial frame is dropped and counted as ``cut``, not as ``incomplete`` (a lost segment). After the
    reset the receiver starts afresh: the rest of the cut frame is a tail heard before any head, cut too,
    and the next frame is assembled from its own segments only."""
    seg = CanSegmenter(NODE, Direction.TO_HOST)
    first, second = (
        seg.segment(encode_frame(ActuatorSetpoint(units=(UnitSetpoint(g, 2.0),) * 4), n))
        for g, n in ((0.5, 1), (0.25, 2))
    )
    assert len(first) > 2
    rx = CanReassembler(NODE, Direction.TO_HOST)
    assert b"".join(rx.feed(f.arbitration_id, f.data) for f in first[:2]) == b""
    rx.reset()
    assert (rx.stats.cut, rx.stats.incomplete, rx.partial_frames) == (1, 0, 0)
    out = b"".join(rx.feed(f.arbitration_id, f.data) for f in first[2:] + second)
    [frame] = Deframer().feed(out)
    assert frame.message.units[0].gimbal == 0.25
    assert (rx.stats.frames, rx.stats.cut, rx.stats.incomplete) == (1, 2, 0)


def test_a_receiver_that_joins_mid_frame_counts_that_tail_as_cut_and_later_losses_as_incomplete():
    """A host that opens its bus while the board streams hears a frame's tail first: that frame was cut by
    the receiver's start, not lost on the link. Once a frame's head has been heard on the arbitration id,
    a frame missing its head is a loss (``incomplete``)."""
    seg = CanSegmenter(NODE, Direction.TO_HOST)
    gimbals = (0.5, 0.25, 0.125, 0.0625)
    frames = [
        seg.segment(encode_frame(ActuatorSetpoint(units=(UnitSetpoint(g, 2.0),) * 4), n))
        for n, g in enumerate(gimbals)
    ]
    assert all(len(f) > 2 for f in frames)
    rx = CanReassembler(NODE, Direction.TO_HOST)
    heard = [
        *frames[0][1:],
        *frames[1],
        *frames[2][1:],
        *frames[3],
    ]  # joined mid-frame 0; frame 2's head lost
    out = b"".join(rx.feed(f.arbitration_id, f.data) for f in heard)
    assert [f.message.units[0].gimbal for f in Deframer().feed(out)] == [0.25, 0.0625]
    assert (rx.stats.frames, rx.stats.cut, rx.stats.incomplete) == (2, 1, 1)


def test_identical_duplicates_are_ignored_and_conflicts_discard_the_frame():
    seg = CanSegmenter(NODE, Direction.TO_BOARD)
    frames = seg.segment(encode_frame(ActuatorSetpoint(units=(UnitSetpoint(1.0, 2.0),) * 3), 7))
    rx = CanReassembler()
    out = b""
    for f in [frames[0], frames[0], *frames[1:]]:
        out += rx.feed(f.arbitration_id, f.data)
    assert Deframer().feed(out)[0].message.units[0].gimbal == 1.0
    assert rx.stats.duplicates == 1
    # A segment with the same transfer id and index but other bytes: the partial frame is dropped.
    frames = seg.segment(encode_frame(ActuatorSetpoint(units=(UnitSetpoint(1.0, 2.0),) * 3), 8))
    forged = CanFrame(frames[1].arbitration_id, frames[1].data[:1] + bytes(7 * [0x11]))
    for f in [frames[0], frames[1], forged, *frames[2:]]:
        out = rx.feed(f.arbitration_id, f.data)
    assert out == b"" and rx.stats.incomplete == 1


@pytest.mark.parametrize(
    ("data", "fd"),
    [
        (b"\x00", False),  # header only
        (b"\x00" + bytes(range(1, 9)), False),  # 9 bytes on classic CAN
        (bytes([37]) + bytes(range(1, 8)), False),  # index 37 > 36
        (bytes([5]) + bytes(range(1, 8)), True),  # index 5 > 4 on FD
        (bytes([1]) + b"\x01\x02\x03", False),  # a middle segment that is not full
        (b"\x00" + bytes(range(1, 65)), True),  # 65 bytes
    ],
)
def test_malformed_segments_are_counted(data, fd):
    rx = CanReassembler()
    assert rx.feed(CanId(Priority.COMMAND, Direction.TO_BOARD, NODE).value, data, fd) == b""
    assert rx.stats.malformed == 1 and rx.stats.segments == 0


def test_memory_is_bounded_whatever_arrives():
    rng = random.Random(3)
    rx = CanReassembler(window=2, max_streams=8)
    for _ in range(20_000):
        arb = CanId(Priority(rng.randrange(7)), Direction(rng.randrange(2)), rng.randrange(128)).value
        data = bytes([rng.randrange(256)]) + bytes(rng.randrange(1, 256) for _ in range(7))
        rx.feed(arb, data)
        assert rx.partial_frames <= 2 * 8
    assert rx.stats.segments > 0 and rx.stats.incomplete > 0


@given(messages(), st.integers(0, 127))
def test_any_node_and_message_round_trip(msg, node):
    wire = encode_frame(msg, 0)
    seg = CanSegmenter(node, Direction.TO_HOST, fd=True)
    rx = CanReassembler(node, Direction.TO_HOST)
    out = b"".join(rx.feed(f.arbitration_id, f.data, True) for f in seg.segment(wire))
    assert out == wire


def test_eight_unit_setpoints_fit():
    wire = encode_frame(ActuatorSetpoint(units=(UnitSetpoint(),) * MAX_UNITS), 0)
    assert len(CanSegmenter(0, Direction.TO_BOARD, fd=True).segment(wire)) == 2


@pytest.mark.parametrize("fd", [False, True])
def test_double_reception_delivers_each_frame_once(fd):
    """CAN controllers can receive a frame twice (a retransmission after an error frame); a repeat of an
    already delivered frame is a counted duplicate, also across transfer-id wrap-around."""
    seg = CanSegmenter(NODE, Direction.TO_HOST, fd=fd)
    rx = CanReassembler(NODE, Direction.TO_HOST)
    framer = Framer()
    deframer = Deframer()
    sent = [Heartbeat(time_ms=7, state=2) for _ in range(9)]  # identical but for seq
    events = []
    for msg in sent:
        for f in seg.segment(framer.encode(msg)[1]):
            events += deframer.feed(rx.feed(f.arbitration_id, f.data, fd))
            events += deframer.feed(rx.feed(f.arbitration_id, f.data, fd))  # received twice
    assert [e.seq for e in events] == list(range(9))
    assert rx.stats.frames == 9 and rx.stats.incomplete == 0
    assert rx.stats.duplicates == sum(len(seg.segment(encode_frame(m, 0))) for m in sent)


@pytest.mark.parametrize("fd", [False, True])
def test_byte_identical_frames_one_after_another_are_all_delivered(fd):
    """A sender's frame equal byte for byte to one it sent four transfer ids before is new, not a
    repeat: a command retransmitted under its sequence number (five tries), or a stream of one frame
    written again and again. Each one is delivered (only a repeat of the frame just delivered is not)."""
    seg = CanSegmenter(NODE, Direction.TO_BOARD, fd=fd)
    rx = CanReassembler(NODE, Direction.TO_BOARD)
    wire = encode_frame(ActuatorSetpoint(units=(UnitSetpoint(0.1, 300.0),) * 4), 17)
    delivered = []
    for _ in range(9):
        for f in seg.segment(wire):
            delivered.append(rx.feed(f.arbitration_id, f.data, fd))
    assert [d for d in delivered if d] == [wire] * 9
    assert rx.stats.frames == 9 and rx.stats.duplicates == 0 and rx.stats.incomplete == 0

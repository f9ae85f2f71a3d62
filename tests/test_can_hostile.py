"""The CAN link beside its path: traffic that is well-formed CAN but hostile (other nodes, other kinds of
frame, error and remote frames, odd lengths, floods), segmentation gone wrong (loss, duplication,
reordering, a sender restarting mid-frame), and the bus failing at drawn moments. Each must end as a
typed error naming where, or a counted drop — never a crash, a hang, unbounded memory or wrong data."""

from __future__ import annotations

import errno
import itertools
import random
import socket
import time
from types import SimpleNamespace

import can
import hypothesis.strategies as st
import pytest
from can_support import multicast_url, read_until, virtual_url
from hypothesis import given, settings
from test_protocol_strategies import extreme_message, numbered_stream

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import (
    FD_LENGTHS,
    CanId,
    CanReassembler,
    CanSegmenter,
    Direction,
    Priority,
    max_segments,
    segment_payload,
)
from protocol.errors import LinkError
from protocol.frame import Deframer, Framer, encode_frame
from protocol.messages import ActuatorSetpoint, Arm, HelloReply, Telemetry, UnitSetpoint

NODE = 5
_seq = itertools.count()


def _wire(gimbal: float = 0.5) -> bytes:
    """A wire frame of several classic segments (one FD segment), unique by its sequence number."""
    return encode_frame(ActuatorSetpoint(units=(UnitSetpoint(gimbal, 300.0),) * 4), next(_seq) & 0xFF)


def _board_segments(wire: bytes, fd: bool = False, node: int = NODE) -> list:
    return CanSegmenter(node, Direction.TO_HOST, fd=fd).segment(wire)


def _msg(arbitration_id: int, data: bytes, **kw) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False, **kw)


def _put(bus: can.BusABC, segments, **kw) -> None:
    for s in segments:
        bus.send(_msg(s.arbitration_id, s.data, is_fd=s.is_fd, **kw))


@pytest.fixture
def bus_and_host():
    """A raw python-can bus (the other nodes) and a host's CAN transport on one virtual channel."""

    def make(fd: bool = False):
        url = virtual_url(fd=fd, node=NODE)
        channel = url.removeprefix("can://virtual/").partition("?")[0]
        raw = can.Bus(interface="virtual", channel=channel, fd=True)
        host = CanTransport(url).open()
        opened.append((raw, host))
        return raw, host

    opened: list = []
    yield make
    for raw, host in opened:
        host.close()
        raw.shutdown()


# =========================================================================== other nodes, other kinds
@pytest.mark.parametrize("link_fd", [False, True], ids=["classic-link", "fd-link"])
def test_frames_of_the_other_kind_are_counted_never_delivered(bus_and_host, link_fd):
    """Before: a classic link delivered a frame another node sent as CAN FD (with BRS), and an FD link one
    sent as classic segments — and a frame assembled from both kinds joined pieces of different sizes."""
    raw, host = bus_and_host(link_fd)
    wire = _wire()
    other = _board_segments(wire, fd=not link_fd)
    _put(raw, other, bitrate_switch=not link_fd)
    assert host.read(0.1) == b""
    counters = host.counters()
    assert counters["rx_wrong_kind"] == len(other) and counters["rx_frames"] == 0
    assert counters["rx_segments"] == 0  # the board's stream is untouched
    mine = _wire(0.25)
    _put(raw, _board_segments(mine, fd=link_fd))
    assert read_until(host, 1) == mine


def test_one_frame_is_never_assembled_from_both_kinds():
    """A receiver that accepts both kinds (``fd=None``) still never joins a classic segment to an FD one:
    an FD segment 0 holding the frame's first 63 bytes, then classic segments 1.. holding the rest, put
    the frame's bytes together exactly — before, that was delivered, segments of different sizes placed
    by index as if they were one sender's."""
    wire = encode_frame(extreme_message(HelloReply, largest=True), 1)
    assert len(wire) > 63 + 7
    arb = CanSegmenter(NODE, Direction.TO_HOST).arbitration_id(HelloReply.MSG_ID)
    rx = CanReassembler(NODE, Direction.TO_HOST)
    out = rx.feed(arb, bytes([0]) + wire[:63], True)
    rest = wire[63:]
    for k, start in enumerate(range(0, len(rest), 7), start=1):
        out += rx.feed(arb, bytes([k]) + rest[start : start + 7], False)
    assert out == b"" and rx.stats.frames == 0 and rx.stats.incomplete == 1


def test_error_and_remote_frames_are_never_segments():
    """Before: ``feed_message`` fed an error frame's data (the controller's error report, 8 bytes on
    socketcan, its id the error class: here one in the scheme) to reassembly — one shaped like a segment
    was delivered as the board's frame."""
    wire = _wire()
    [segment] = _board_segments(wire, fd=True)
    rx = CanReassembler(NODE, Direction.TO_HOST)
    err = can.Message(
        arbitration_id=segment.arbitration_id, data=segment.data, is_fd=True, is_error_frame=True
    )
    rtr = can.Message(
        arbitration_id=segment.arbitration_id, is_remote_frame=True, dlc=8, is_extended_id=False
    )
    assert rx.feed_message(err) == b"" and rx.feed_message(rtr) == b""
    assert rx.stats.error_frames == 2 and rx.stats.segments == 0 and rx.stats.frames == 0


def test_zero_byte_odd_length_and_delimiter_only_frames_are_malformed_and_harmless(bus_and_host):
    """On the board's own id, mid-frame: a 0-byte frame, an FD frame of a length CAN FD does not have (13),
    a first segment holding only the delimiter (a frame of no bytes) at 2 and at 12 bytes, and a one-segment
    FD frame of 64 bytes that fails its CRC. Before: the delimiter-only segment of another transfer id
    ended the board's frame in flight (lost, counted ``incomplete``) and the others were miscounted as
    ``spliced`` and ``duplicates``; now each is ``malformed`` and the board's frame arrives."""
    raw, host = bus_and_host(False)
    wire = _wire()
    segments = _board_segments(wire)
    arb = segments[0].arbitration_id
    _put(raw, segments[:3])
    hostile = [
        _msg(arb, b""),
        _msg(arb, bytes([0x40]) + bytes(range(1, 13)), is_fd=True),  # 13 bytes: no CAN FD length
        _msg(arb, b"\x40\x00"),  # another transfer id's frame of no bytes
        _msg(arb, b"\x80" + bytes(11), is_fd=True),
        _msg(arb, b"\xc0" + bytes(range(1, 63)) + b"\x00", is_fd=True),  # one segment, CRC fails
    ]
    for m in hostile:
        raw.send(m)
    _put(raw, segments[3:])
    assert read_until(host, 1) == wire
    c = host.counters()
    assert c["rx_frames"] == 1 and c["rx_incomplete"] == 0 and c["rx_spliced"] == 0
    assert c["rx_duplicates"] == 0
    assert c["rx_malformed"] + c["rx_wrong_kind"] == len(hostile)


def test_a_one_segment_fd_frame_that_fails_its_crc_is_malformed_not_a_splice():
    rx = CanReassembler(NODE, Direction.TO_HOST, fd=True)
    arb = CanId(Priority.STATUS, Direction.TO_HOST, NODE).value
    assert rx.feed(arb, b"\x00" + bytes(range(1, 20)) + b"\x00" + bytes(3), True) == b""
    assert (rx.stats.malformed, rx.stats.spliced, rx.partial_frames) == (1, 0, 0)


def test_another_node_s_complete_frames_and_a_flood_are_counted_with_bounded_memory(bus_and_host):
    """A node with another number sends whole, well-formed frames on the board's priorities; another floods
    the bus with random segments on every id. Nothing of theirs is delivered, memory stays bounded, each
    CAN frame is counted, and the board's frame after the flood arrives."""
    raw, host = bus_and_host(False)
    rng = random.Random(7)
    foreign = _board_segments(_wire(), node=NODE + 1) + _board_segments(_wire(), node=0)
    _put(raw, foreign)
    flood = 5000
    for _ in range(flood):
        arb = CanId(Priority(rng.randrange(7)), Direction(rng.randrange(2)), rng.choice((NODE + 1, 9))).value
        raw.send(_msg(arb, bytes(rng.randrange(256) for _ in range(rng.randrange(9)))))
    assert host.read(0.2) == b""
    while host.read(0.0):
        pass
    wire = _wire()
    _put(raw, _board_segments(wire))
    assert read_until(host, 1) == wire
    c = host.counters()
    assert c["rx_ignored"] == len(foreign) + flood and c["rx_frames"] == 1
    assert host._reassembler.partial_frames <= 2 * 7


# =========================================================================== segmentation (Hypothesis)
def _foreign_pool(fd: bool) -> list[SimpleNamespace]:
    """CAN frames a receiver of node NODE, direction TO_HOST, kind ``fd`` must count and otherwise ignore
    (never letting them touch the board's streams), with the counter each one lands in."""
    mine = CanId(Priority.STATUS, Direction.TO_HOST, NODE).value
    other_node = CanId(Priority.STATUS, Direction.TO_HOST, NODE + 1).value
    wrong_way = CanId(Priority.STATUS, Direction.TO_BOARD, NODE).value
    limit = 64 if fd else 8
    seg = _board_segments(_wire(0.125), fd=fd)[0]

    def m(kind: str, arb: int, data: bytes, **kw) -> SimpleNamespace:
        fields = {"is_fd": fd, "is_extended_id": False, "is_error_frame": False, "is_remote_frame": False}
        return SimpleNamespace(kind=kind, arbitration_id=arb, data=data, **{**fields, **kw})

    return [
        m("ignored", other_node, seg.data),
        m("ignored", wrong_way, seg.data),
        m("ignored", mine, seg.data, is_extended_id=True),
        m("ignored", 0x7FF, seg.data),
        m("wrong_kind", mine, seg.data[:8], is_fd=not fd),
        m("error_frames", mine, seg.data, is_error_frame=True),
        m("error_frames", mine, b"", is_remote_frame=True),
        m("malformed", mine, b""),
        m("malformed", mine, b"\x00"),
        m("malformed", mine, bytes(limit + 1)),
        m("malformed", mine, bytes([max_segments(fd)]) + bytes(range(1, limit))),  # index out of range
        m("malformed", mine, bytes([0x41]) + b"\x01\x02"),  # a middle segment that is not full
        m("malformed", mine, b"\x80\x00"),  # a first segment holding only the delimiter
        *([m("malformed", mine, bytes([0xC1]) + bytes(range(1, 12)) + b"\x00")] if fd else []),  # 13 bytes
    ]


FATES = ("ok", "ok", "ok", "ok", "lost", "dup_now", "dup_later")


@settings(max_examples=120, deadline=None)
@given(numbered_stream(max_frames=14), st.booleans(), st.data())
def test_any_loss_duplication_reordering_restart_and_noise_yields_only_whole_correct_frames(stream, fd, data):
    """Each frame's segments in any order; each segment heard, lost, received twice at once (CAN's double
    reception) or repeated later within its frame; the sender restarting mid-frame (its transfer ids from
    0 again); foreign and malformed CAN frames anywhere. Delivered: only frames the sender sent, byte for
    byte, each once, in order on their arbitration id; every frame whose segments all arrived, unless the
    transfer id wrapped onto a frame still held (the frame heard last on its id had the same transfer id,
    or a restart began the id's ids again). The rest is counted; memory stays bounded."""
    seg = CanSegmenter(NODE, Direction.TO_HOST, fd=fd)
    pool = _foreign_pool(fd)
    heard: list = []  # (frame index or None, message-like)
    must: set[int] = set()
    started: set[int] = set()
    last_tid: dict[int, int] = {}  # per arbitration id: the transfer id of the last frame heard there
    fresh: set[int] = set()  # arbitration ids whose transfer ids a restart began again
    expected = {"ignored": 0, "wrong_kind": 0, "error_frames": 0, "malformed": 0}
    arb_of: dict[int, int] = {}

    def noise() -> None:
        for f in data.draw(st.lists(st.sampled_from(pool), max_size=2)):
            heard.append((None, f))
            expected[f.kind] += 1

    for i, (_, wire) in enumerate(stream):
        segments = seg.segment(wire)
        arb, tid = segments[0].arbitration_id, segments[0].data[0] >> 6
        order = data.draw(st.permutations(range(len(segments))))
        fates = data.draw(st.lists(st.sampled_from(FATES), min_size=len(order), max_size=len(order)))
        restart_after = (
            data.draw(st.one_of(st.none(), st.integers(0, len(order) - 1))) if i % 3 == 2 else None
        )
        sent = order if restart_after is None else order[:restart_after]
        whole = restart_after is None and "lost" not in fates
        if whole and last_tid.get(arb, -1) != tid and arb not in fresh:
            must.add(i)
        arb_of[i] = arb
        mine = []
        later = []
        for k, fate in zip(sent, fates, strict=False):
            if fate == "lost":
                continue
            s = SimpleNamespace(arbitration_id=arb, data=segments[k].data, is_fd=fd, is_extended_id=False)
            mine.append(s)
            if fate == "dup_now":
                mine.append(s)
            elif fate == "dup_later":
                later.append(s)
        for s in later:  # a repeat anywhere after its original, within its frame or just after it
            mine.insert(data.draw(st.integers(mine.index(s) + 1, len(mine))), s)
        for s in mine:
            heard.append((i, s))
            noise()
        if mine:
            started.add(i)
            last_tid[arb] = tid
            fresh.discard(arb)
        if restart_after is not None:
            seg = CanSegmenter(NODE, Direction.TO_HOST, fd=fd)  # the sender restarts: transfer ids from 0
            fresh = set(last_tid)
    rx = CanReassembler(NODE, Direction.TO_HOST, fd=fd)
    wires = {wire: i for i, (_, wire) in enumerate(stream)}
    delivered: list[int] = []
    for _, m in heard:
        m = SimpleNamespace(**{"is_error_frame": False, "is_remote_frame": False, **vars(m)})
        out = rx.feed_message(m)
        assert rx.partial_frames <= rx.window * 7
        if out:
            assert out in wires, "a frame the sender never sent"
            delivered.append(wires[out])
    assert len(set(delivered)) == len(delivered), "a frame delivered twice"
    for arb in set(arb_of.values()):
        on_id = [i for i in delivered if arb_of[i] == arb]
        assert on_id == sorted(on_id)
    assert must <= set(delivered), (sorted(must - set(delivered)), rx.stats)
    c = rx.stats
    assert c.frames == len(delivered)
    assert (c.ignored, c.wrong_kind, c.error_frames) == (
        expected["ignored"],
        expected["wrong_kind"],
        expected["error_frames"],
    )
    assert c.malformed >= expected["malformed"]
    rx.reset()
    assert rx.partial_frames == 0
    if started - set(delivered):
        assert c.incomplete + c.cut + c.spliced + c.duplicates + c.malformed - expected["malformed"] >= 1
    assert all(Deframer().feed(stream[i][1]) for i in delivered)


def test_a_sender_restarting_mid_frame_costs_that_frame_only():
    """The board restarts with a frame half sent; its next frame reuses transfer id 0: the half frame is
    counted (``incomplete``), never completed from the new frame's segments; the new frame arrives."""
    old, new = _wire(0.5), _wire(0.25)
    first = _board_segments(old)  # transfer id 0
    second = _board_segments(new)  # a new segmenter: transfer id 0 again
    rx = CanReassembler(NODE, Direction.TO_HOST)
    out = b"".join(rx.feed(f.arbitration_id, f.data) for f in first[:3] + second)
    assert out == new and (rx.stats.frames, rx.stats.incomplete) == (1, 1)


def test_an_absurd_segment_index_in_range_from_a_third_node_is_counted_not_delivered():
    """A last segment at index 36 (in range on classic CAN) in the board's transfer id: the board's frame
    cannot complete with it, is counted, and the board's next frame arrives."""
    wire, after = _wire(0.5), _wire(0.25)
    seg = CanSegmenter(NODE, Direction.TO_HOST)
    a, b = seg.segment(wire), seg.segment(after)
    rx = CanReassembler(NODE, Direction.TO_HOST)
    out = rx.feed(a[0].arbitration_id, bytes([max_segments(False) - 1]) + b"\x01\x02\x00")
    out += b"".join(rx.feed(f.arbitration_id, f.data) for f in a + b)
    assert out == after  # the poisoned frame is lost, never anything else delivered
    assert rx.stats.frames == 1 and rx.stats.incomplete >= 1


# =========================================================================== the bus failing
def test_a_full_transmit_queue_drops_the_frame_counted_not_the_link(bus_and_host, caplog):
    """socketcan refuses a send with ENOBUFS when its queue is full ("No buffer space available"). Before:
    a LinkError ("interface gone?"), so the board client closed and reopened a bus that was there — and
    handshook again, disarming the board. Now the frame is dropped and counted, the warning logged once."""
    raw, host = bus_and_host(False)
    real_send = host._bus.send
    full = {"left": 3}

    def send(msg, timeout=None):
        if full["left"]:
            full["left"] -= 1
            try:
                raise OSError(errno.ENOBUFS, "No buffer space available")
            except OSError as error:
                raise can.CanOperationError(
                    "Failed to transmit: No buffer space available", error.errno
                ) from error
        real_send(msg, timeout)

    host._bus.send = send
    frames = [Framer().encode(Arm())[1] for _ in range(4)]
    for wire in frames:
        host.write(wire)
    assert host.counters()["tx_frames_dropped"] == 3 and host.counters()["tx_frames_sent"] == 1
    assert sum("transmit queue full" in r.getMessage() for r in caplog.records) == 1
    got = b""
    for _ in range(20):
        if (msg := raw.recv(0.02)) is not None:
            got += msg.data[1:]
    assert got.rstrip(b"\x00") + b"\x00" == frames[3]


def test_any_other_send_failure_is_a_link_error_naming_the_bus(bus_and_host):
    raw, host = bus_and_host(False)

    def send(msg, timeout=None):
        raise can.CanOperationError("bus off")

    host._bus.send = send
    with pytest.raises(LinkError, match=r"can://virtual/.*send failed.*bus off"):
        host.write(Framer().encode(Arm())[1])


@pytest.mark.parametrize("at", range(4))
def test_a_receive_failure_at_any_moment_hands_up_the_frames_completed_first(bus_and_host, at):
    """The bus fails after ``at`` CAN messages of a read. Before: frames already completed in that read
    were lost with the LinkError; now they are handed up and the error is raised by the next read."""
    raw, host = bus_and_host(True)
    wires = [_wire(0.5), _wire(0.25), _wire(0.125)]
    for w in wires:
        _put(raw, _board_segments(w, fd=True))
    time.sleep(0.05)
    real_recv = host._bus.recv
    calls = itertools.count()

    def recv(timeout=None):
        if next(calls) == at:
            raise can.CanOperationError("Failed to receive: Network is down", errno.ENETDOWN)
        return real_recv(timeout)

    host._bus.recv = recv
    got = b""
    if at:
        got = host.read(0.1)
        assert got == b"".join(wires[:at])
    with pytest.raises(LinkError, match="receive failed"):
        host.read(0.1)


def test_a_bus_closed_under_a_read_is_a_link_error_not_an_assertion(bus_and_host):
    raw, host = bus_and_host(False)
    bus, host._bus = host._bus, None  # what close() on another thread does between read's check and recv
    try:
        with pytest.raises(LinkError, match="closed during a read"):
            host.read(0.01)
        with pytest.raises(LinkError, match="closed during a write"):
            host.write(Framer().encode(Arm())[1])
    finally:
        host._bus = bus


# =========================================================================== udp_multicast: other programs
def _group(url: str) -> tuple[str, int]:
    group, _, rest = url.removeprefix("can://udp_multicast/").partition("?port=")
    return group, int(rest.partition("&")[0])


def _datagram(url: str, payload: bytes) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        s.sendto(payload, _group(url))


@pytest.mark.udp_multicast
def test_an_undecodable_datagram_on_the_group_is_counted_not_a_lost_link():
    """Another program sends a datagram to the bus's multicast group that python-can cannot unpack. Before:
    a LinkError on the host (a reconnection and a new handshake for one stray datagram) and, on the board's
    side, firmware-sim's serving thread dead; now counted (``rx_undecodable``) and skipped."""
    url = multicast_url(node=NODE)
    board = Board(BoardConfig(n_units=2, telemetry_rate_hz=50.0), WallClock())
    with CanTransport(url) as host, CanServer(board, url) as server:
        server.start()
        for _ in range(3):
            _datagram(url, b"not msgpack at all")
        wire = Framer().encode(Telemetry(time_ms=5, pulses_us=(1500,) * 8))[1]
        with CanTransport(url, sends=Direction.TO_HOST) as other:
            other.write(wire)
        got = b""
        for _ in range(50):
            got += host.read(0.02)
            if host.counters()["rx_undecodable"] >= 3 and got:
                break
        assert host.counters()["rx_undecodable"] == 3
        assert wire in got
        time.sleep(0.1)
        server.check()  # the serving thread lived through the datagrams
        assert server.counters()["rx_undecodable"] >= 3


def test_segment_payload_sizes_are_those_the_fd_lengths_allow():
    assert segment_payload(False) == 7 and segment_payload(True) + 1 in FD_LENGTHS

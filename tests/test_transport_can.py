"""The can:// transport on real python-can buses (the in-process ``virtual`` interface): the protocol's byte
stream in segments, reassembled; lost, foreign and malformed traffic counted, never delivered."""

from __future__ import annotations

import itertools
import os

import can
import pytest
from can_support import read_until

from hil.link.transports import create_transport, open_transport
from hil.link.transports.can_bus import CanTransport
from protocol.can import CanSegmenter, Direction
from protocol.errors import TransportError
from protocol.frame import Framer, decode_stream
from protocol.messages import ActuatorSetpoint, Arm, Heartbeat, Telemetry, UnitSetpoint

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    """A virtual channel no other test (or engineer's test run in this process) uses."""
    return f"test-can-{os.getpid()}-{next(_channels)}"


@pytest.mark.parametrize("fd", [False, True])
def test_frames_cross_the_bus_both_ways_whatever_the_write_chunking(channel, fd):
    framer = Framer()
    frames = [
        framer.encode(ActuatorSetpoint(units=tuple(UnitSetpoint(0.1 * i, 100.0 * i) for i in range(4))))[1],
        framer.encode(Arm())[1],
        framer.encode(Heartbeat(time_ms=123456, state=0))[1],
    ]
    stream = b"".join(frames)
    url = f"can://virtual/{channel}?node=7&fd={int(fd)}"
    with open_transport(url) as host, CanTransport(url, sends=Direction.TO_HOST) as board:
        for i in range(0, len(stream), 5):  # a frame's bytes arrive in several writes
            host.write(stream[i : i + 5])
        assert read_until(board, 3) == stream
        tel = Framer().encode(Telemetry(time_ms=5, pulses_us=(1500,) * 8))[1]
        board.write(b"\x00\x00" + tel)  # idle fill before the frame is not sent
        assert read_until(host, 1) == tel
        per_segment = 63 if fd else 7
        expected = sum(-(-len(f) // per_segment) for f in frames)
        assert host.counters()["tx_segments_sent"] == expected
        assert board.counters()["rx_segments"] == expected and board.counters()["rx_frames"] == 3
        assert host.counters()["rx_frames"] == 1


def test_a_lost_segment_costs_that_frame_only_and_is_counted(channel):
    url = f"can://virtual/{channel}?node=3"
    framer = Framer()
    first = framer.encode(ActuatorSetpoint(units=(UnitSetpoint(0.5, 200.0),) * 4))[1]
    second = framer.encode(ActuatorSetpoint(units=(UnitSetpoint(0.2, 300.0),) * 4))[1]
    segmenter = CanSegmenter(3, Direction.TO_BOARD)
    with (
        can.Bus(interface="virtual", channel=channel) as raw,
        CanTransport(url, sends=Direction.TO_HOST) as board,
    ):
        lost = segmenter.segment(first)
        for seg in lost[:2] + lost[3:]:  # segment 2 never arrives
            raw.send(can.Message(arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False))
        for seg in segmenter.segment(second):
            raw.send(can.Message(arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False))
        got = read_until(board, 1)
        assert got == second
        [event] = decode_stream(got)
        assert event.message.units[0].rotor_speed == 300.0
        assert board.counters()["rx_incomplete"] == 1


def test_foreign_traffic_is_ignored_and_counted(channel):
    url = f"can://virtual/{channel}?node=3"
    wire = Framer().encode(Arm())[1]
    with (
        can.Bus(interface="virtual", channel=channel) as raw,
        CanTransport(url, sends=Direction.TO_HOST) as board,
    ):
        other_node = CanSegmenter(4, Direction.TO_BOARD).segment(wire)
        wrong_way = CanSegmenter(3, Direction.TO_HOST).segment(wire)
        for seg in other_node + wrong_way:
            raw.send(can.Message(arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False))
        raw.send(can.Message(arbitration_id=0x12345, data=b"\x01\x02", is_extended_id=True))
        raw.send(can.Message(arbitration_id=0x003, is_error_frame=True))
        raw.send(can.Message(arbitration_id=0x003, data=b"\x00", is_extended_id=False))  # too short
        assert board.read(0.1) == b""
        counters = board.counters()
        assert counters["rx_ignored"] == len(other_node) + len(wrong_way) + 1
        assert counters["rx_error_frames"] == 1 and counters["rx_malformed"] == 1
        assert counters["rx_frames"] == 0


def test_bytes_that_are_not_a_frame_are_counted_not_sent(channel):
    url = f"can://virtual/{channel}"
    with open_transport(url) as host, CanTransport(url, sends=Direction.TO_HOST) as board:
        host.write(b"\x05" * 300)  # no delimiter within a frame's length
        host.write(b"\x00")
        assert board.read(0.05) == b""
        assert host.counters()["tx_not_frames"] == 1 and host.counters()["tx_frames_sent"] == 0
        wire = Framer().encode(Arm())[1]
        host.write(wire)  # the stream recovers at the next delimiter
        assert read_until(board, 1) == wire


@pytest.mark.parametrize(
    ("url", "match"),
    [
        ("can://virtual", "expected can://<interface>/<channel>"),
        ("can://virtual/x?node=200", "node=200 is outside 0..127"),
        ("can://virtual/x?nodes=2", "unknown option"),
        ("can://virtual/x?fd=maybe", "not a boolean"),
        ("can://virtual/x?bitrate=fast", "not an integer"),
        ("can://virtual/x?send_timeout=-1", "send_timeout"),
    ],
)
def test_bad_urls_are_transport_errors_naming_the_url(url, match):
    with pytest.raises(TransportError, match=match):
        create_transport(url)


def test_an_interface_that_is_not_there_is_a_transport_error_at_open():
    transport = create_transport("can://no_such_interface/x")
    with pytest.raises(TransportError, match="no_such_interface"):
        transport.open()
    assert not transport.is_open


def test_slcan_style_channels_keep_their_device_path():
    transport = create_transport("can://slcan//dev/ttyACM0?bitrate=500000")
    assert isinstance(transport, CanTransport)
    assert (transport.interface, transport.channel) == ("slcan", "/dev/ttyACM0")

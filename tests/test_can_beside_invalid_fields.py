"""Messages python-can hands over whose fields are not a CAN frame's.

python-can's udp_multicast interface builds a ``Message`` from whatever a datagram on its group says once
``Message(check=True)`` passes — and that check lets an arbitration id of 901.5 through, or a flag of 2 —
and the virtual interface passes on whatever message another thread built. Before, a float id made
``CanTransport.read`` raise TypeError (``float >> int`` in ``CanId.parse``): the host's client ended with
"the reader thread failed" and ``firmware-sim --can`` exited 1 with a traceback. Now every such message is
counted (``rx_invalid``), logged at a bounded rate and dropped, on both ends, and the link goes on."""

from __future__ import annotations

import logging
import random
import socket
import time

import can
import hypothesis.strategies as st
import msgpack
import pytest
from can_support import read_until, virtual_url
from hypothesis import HealthCheck, given, settings

from bench.child import firmware_sim, started
from hil.link.transports.can_bus import CanTransport
from protocol.can import CanId, Direction, Priority
from protocol.frame import Framer
from protocol.messages import Heartbeat, Hello, Telemetry

NODE = 5
_OTHER = CanId(Priority.STATUS, Direction.TO_HOST, NODE + 1).value  # a well-formed id of another node

_VALID = {
    "arbitration_id": _OTHER,
    "data": bytearray(b"\x01\x02\x03"),
    "dlc": 3,
    "is_extended_id": False,
    "is_fd": False,
    "is_error_frame": False,
    "is_remote_frame": False,
}
_NOT_A_FLAG = st.one_of(
    st.integers().filter(lambda n: n not in (0, 1)), st.floats(), st.text(max_size=3), st.none(), st.just([])
)
_BAD = {
    "arbitration_id": st.one_of(
        st.floats(),  # 901.0 is no integer either: python-can would carry it as a float
        st.integers(max_value=-1),
        st.integers(min_value=1 << 11),  # a standard id is 11 bits
        st.booleans(),
        st.text(max_size=3),
        st.none(),
    ),
    # python-can makes a bytearray of the data whatever it is (the virtual bus copies each message through
    # its constructor): what can reach a receiver is a length other than the dlc's
    "data": st.one_of(
        st.integers(0, 8).filter(lambda n: n != 3),
        st.none(),
        st.lists(st.integers(0, 255), max_size=8).filter(lambda b: len(b) != 3),
    ),
    "dlc": st.one_of(st.integers().filter(lambda n: n != 3), st.floats(), st.text(max_size=2), st.booleans()),
    "is_extended_id": _NOT_A_FLAG,
    "is_fd": _NOT_A_FLAG,
    "is_error_frame": _NOT_A_FLAG,
    "is_remote_frame": _NOT_A_FLAG,
}


@st.composite
def _hostile(draw) -> dict[str, object]:
    """A message's fields, one of them (at least) of the wrong type or out of CAN's range."""
    fields = dict(_VALID, data=bytearray(_VALID["data"]))
    for name in draw(st.lists(st.sampled_from(sorted(_BAD)), min_size=1, max_size=3, unique=True)):
        fields[name] = draw(_BAD[name])
    data, dlc = fields["data"], fields["dlc"]
    length = 0 if data is None else data if isinstance(data, int) else len(data)  # as the bus's copy has it
    if type(dlc) is int and dlc == length:  # data and dlc both drawn, and they agree: a valid frame's pair
        fields["dlc"] = length + 1
    return fields


def _message(fields: dict[str, object]) -> can.Message:
    """A python-can message carrying ``fields`` as they are (set after construction: the constructor
    would turn data into a bytearray)."""
    msg = can.Message(check=False)
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hostile=st.lists(_hostile(), min_size=1, max_size=6), sends=st.sampled_from(list(Direction)))
def test_every_message_with_a_field_of_the_wrong_type_is_counted_and_dropped_never_raised(hostile, sends):
    """On a real virtual bus: whatever the wrong field, on either end (a host, or the board's side as
    firmware-sim's CanServer opens it), the read neither raises nor delivers it, counts each one as
    ``rx_invalid``, and the peer's next frame still arrives."""
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    peer_sends = Direction.TO_HOST if sends is Direction.TO_BOARD else Direction.TO_BOARD
    try:
        with CanTransport(url, sends=sends) as end, CanTransport(url, sends=peer_sends) as peer:
            for fields in hostile:
                raw.send(_message(fields))
            wire = Framer().encode(Heartbeat(time_ms=7))[1]
            peer.write(wire)
            got = read_until(end, 1, tries=10)
            assert got == wire
            counters = end.counters()
            assert counters["rx_invalid"] == len(hostile), counters
            assert counters["rx_malformed"] == counters["rx_incomplete"] == 0
    finally:
        raw.shutdown()


def test_an_invalid_message_is_logged_at_a_bounded_rate(caplog):
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with caplog.at_level(logging.WARNING), CanTransport(url) as host:
            for _ in range(200):
                raw.send(_message(dict(_VALID, arbitration_id=901.5)))
            host.read(0.05)
            assert host.counters()["rx_invalid"] == 200
    finally:
        raw.shutdown()
    lines = [r for r in caplog.records if "not a CAN frame's" in r.getMessage()]
    assert len(lines) == 1 and "arbitration_id: float" in lines[0].getMessage()


def _datagram(group: str, port: int, **fields: object) -> None:
    """One datagram on the udp_multicast group, as python-can packs a message, with ``fields`` changed."""
    message = {
        "timestamp": 0.0,
        "arbitration_id": 0x385,
        "is_extended_id": False,
        "is_remote_frame": False,
        "is_error_frame": False,
        "channel": None,
        "dlc": 2,
        "data": b"\x01\x02",
        "is_fd": False,
        "bitrate_switch": False,
        "error_state_indicator": False,
        **fields,
    }
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        s.sendto(msgpack.packb(message, use_bin_type=True), (group, port))


@pytest.mark.udp_multicast
def test_a_float_id_on_the_multicast_group_stops_neither_the_host_nor_firmware_sim():
    """Real processes: firmware-sim serving on a udp_multicast group, a host talking to it, and a third
    program sending datagrams python-can accepts as messages with a float id (towards the host and towards
    the board) and odd flags. Before: the host's read raised TypeError and firmware-sim exited 1 with a
    traceback. Now both count them and the host still hears the board."""
    group, port = f"239.74.166.{random.randint(1, 254)}", random.randint(40_000, 60_000)
    spec = f"udp_multicast/{group}?port={port}&node={NODE}"
    framer = Framer()
    hostile = (
        {"arbitration_id": 0x385 + 0.5},  # towards the host, node 5
        {"arbitration_id": 0x205 + 0.5},  # towards the board, node 5
        {"arbitration_id": float(0x205)},
        {"is_error_frame": 2},  # (an is_fd a non-FD bus drops itself)
        {"is_extended_id": "yes"},
    )
    argv = firmware_sim("--units", "1", "--telemetry-rate", "50", "--can", spec)
    with started(argv) as board, CanTransport(board.first_line) as host:
        host.write(framer.encode(Hello())[1])
        for fields in hostile:
            _datagram(group, port, **fields)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and host.counters()["rx_invalid"] < len(hostile):
            host.write(framer.encode(Heartbeat())[1])
            host.read(0.02)
        assert host.counters()["rx_invalid"] == len(hostile)
        before = host.counters()["rx_frames"]
        for _ in range(20):
            host.write(framer.encode(Heartbeat())[1])
            host.read(0.02)
        assert host.counters()["rx_frames"] > before  # the board still talks
        assert board.proc.poll() is None
        board.stop()
    assert "Traceback" not in board.said
    assert "not a CAN frame's" in board.said
    assert board.proc.returncode == 0  # firmware-sim stops cleanly on SIGTERM


@given(
    fields=_hostile(),
    data=st.one_of(st.text(max_size=4), st.integers(), st.none(), st.lists(st.integers(0, 255), max_size=3)),
    timestamp=st.one_of(st.floats(), st.integers(), st.text(max_size=2), st.none()),
)
def test_the_sans_io_layer_refuses_what_no_bus_carries_without_raising(fields, data, timestamp):
    """``CanReassembler.feed_message`` on its own (a duck-typed message from any source): data that is not
    bytes (``bytes(5)`` would be five zero bytes) and any field of the wrong type are ``invalid``; a
    timestamp that is no finite number is an unknown receive time, never an exception; ``CanId.parse``
    says a float is not in the scheme with the ProtocolError every caller handles. The reassembler then
    still assembles the next frame."""
    from protocol.can import CanReassembler, CanSegmenter
    from protocol.errors import ProtocolError

    with pytest.raises(ProtocolError):
        CanId.parse(901.5)  # type: ignore[arg-type]
    rx = CanReassembler(NODE, Direction.TO_HOST)
    for message in (_message(fields), _message(dict(_VALID, data=data))):
        message.timestamp = timestamp
        assert rx.feed_message(message) == b""
    assert rx.stats.invalid == 2
    wire = Framer().encode(Telemetry(time_ms=1, pulses_us=(1500,) * 8))[1]
    out = b""
    for seg in CanSegmenter(NODE, Direction.TO_HOST).segment(wire):
        message = _message(dict(_VALID, arbitration_id=seg.arbitration_id, data=seg.data, dlc=len(seg.data)))
        message.timestamp = timestamp
        out += rx.feed_message(message)
    assert out == wire

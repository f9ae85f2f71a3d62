"""A datagram on the ``udp_multicast`` group whose ``data`` is an integer: python-can hands ``data`` to
``bytearray()`` before its own check, which takes an integer as a size — one 157-byte datagram from any
program on the group made the host (and firmware-sim) allocate hundreds of megabytes of zeros and spend
seconds on it before the message was refused. Now it is refused before python-can builds the message,
counted ``rx_undecodable`` and logged like any datagram python-can cannot unpack, at no memory; the link
goes on."""

from __future__ import annotations

import socket
import tracemalloc

import hypothesis.strategies as st
import msgpack
import pytest
from can_support import multicast_url, read_until
from hypothesis import given, settings

from hil.link.transports.can_bus import CanTransport
from protocol.can import CanId, Direction, Priority
from protocol.frame import Framer
from protocol.messages import Heartbeat, Telemetry

NODE = 5
pytestmark = pytest.mark.udp_multicast


def _send_datagram(url: str, payload: bytes) -> None:
    group, _, rest = url.removeprefix("can://udp_multicast/").partition("?port=")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        s.sendto(payload, (group, int(rest.partition("&")[0])))


def _sized(arbitration_id: int, size: int) -> bytes:
    """What python-can's udp_multicast sender packs, but for ``data``: an integer, ``size``."""
    fields = {
        "timestamp": 0.0,
        "arbitration_id": arbitration_id,
        "is_extended_id": False,
        "is_remote_frame": False,
        "is_error_frame": False,
        "channel": None,
        "dlc": 8,
        "data": size,
        "is_fd": False,
        "bitrate_switch": False,
        "error_state_indicator": False,
    }
    return msgpack.packb(fields, use_bin_type=True)


@settings(max_examples=6, deadline=None)
@given(
    size=st.one_of(st.integers(10**7, 3 * 10**8), st.sampled_from([8, 64, 0, -1, 2**63])),
    sends=st.sampled_from([Direction.TO_BOARD, Direction.TO_HOST]),
    how_many=st.integers(1, 3),
)
def test_a_datagram_whose_data_is_a_size_costs_no_memory_and_is_counted(size, sends, how_many):
    url = multicast_url(node=NODE)
    receives = Direction.TO_HOST if sends is Direction.TO_BOARD else Direction.TO_BOARD
    towards_it = CanId(Priority.STATUS, receives, NODE).value  # on this end's own stream, not foreign
    wire = Framer().encode(Telemetry(time_ms=5) if sends is Direction.TO_BOARD else Heartbeat(time_ms=5))[1]
    with CanTransport(url, sends=sends) as end, CanTransport(url, sends=receives) as peer:
        tracemalloc.start()
        try:
            for _ in range(how_many):
                _send_datagram(url, _sized(towards_it, size))
            peer.write(wire)  # the peer's frame after them: still heard
            got = read_until(end, 1)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 8 * 2**20, f"{peak / 2**20:.0f} MiB for {how_many} datagram(s) of data={size}"
        assert end.counters()["rx_undecodable"] == how_many
        assert wire in got

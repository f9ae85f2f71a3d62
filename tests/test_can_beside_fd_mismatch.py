"""The two ends of a CAN link configured for different kinds of frame (``fd=1`` on one, ``fd=0`` on the
other), on python-can's ``udp_multicast`` interface.

A ``udp_multicast`` bus opened with ``fd=False`` drops every CAN FD frame it receives inside python-can
(``_recv_internal`` returns nothing for it): the transport never saw them, counted nothing, logged
nothing, and a host whose board speaks CAN FD waited out its handshake with "no handshake" and no reason
(the ``virtual`` interface hands both kinds up, and there the reassembler counted them, ``rx_wrong_kind``).
Now the transport opens ``udp_multicast`` taking both kinds and its reassembler judges the kind: a frame
of the other kind is counted (``rx_wrong_kind``) and logged naming the ``fd`` option, and a first
handshake that hears only such frames says so in its ``LinkTimeout``."""

from __future__ import annotations

import logging
import random
import time

import can
import pytest

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.board import BoardClient, ClientConfig
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import CanSegmenter, Direction
from protocol.errors import LinkTimeout
from protocol.frame import Framer
from protocol.messages import Heartbeat
from protocol.reliable import RetryPolicy

NODE = 9


def _group() -> tuple[str, int]:
    return f"239.74.167.{random.randint(1, 254)}", random.randint(40_000, 60_000)


@pytest.mark.udp_multicast
@pytest.mark.parametrize("host_fd", [False, True])
def test_frames_of_the_other_kind_are_counted_and_logged_naming_the_option(host_fd, caplog):
    """A raw python-can node on the group sends the board's frames in the kind the host is not set up
    for: the host's transport counts every one (``rx_wrong_kind``) and logs it naming ``fd``; before, a
    classic host (``fd=0``) counted none of the CAN FD ones (python-can dropped them)."""
    group, port = _group()
    url = f"can://udp_multicast/{group}?port={port}&node={NODE}&fd={int(host_fd)}"
    peer_fd = not host_fd
    segmenter = CanSegmenter(NODE, Direction.TO_HOST, fd=peer_fd)
    framer = Framer()
    caplog.set_level(logging.WARNING, logger="hil.link.transports.can_bus")
    with CanTransport(url) as host:
        peer = can.Bus(interface="udp_multicast", channel=group, port=port, fd=True)
        try:
            sent = 0
            for k in range(5):
                for seg in segmenter.segment(framer.encode(Heartbeat(time_ms=k, state=1, boot_id=7))[1]):
                    peer.send(
                        can.Message(
                            arbitration_id=seg.arbitration_id,
                            data=seg.data,
                            is_fd=seg.is_fd,
                            is_extended_id=False,
                        )
                    )
                    sent += 1
            end = time.monotonic() + 2.0
            while host.counters()["rx_wrong_kind"] < sent and time.monotonic() < end:
                assert host.read(0.02) == b""  # never delivered as the host's kind
        finally:
            peer.shutdown()
        counters = host.counters()
    assert counters["rx_wrong_kind"] == sent, counters
    assert counters["rx_frames"] == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "rx_wrong_kind" in said and f"fd={int(host_fd)}" in said, said


@pytest.mark.udp_multicast
def test_a_classic_host_of_a_can_fd_board_is_told_why_the_handshake_failed():
    """The board served on the group with ``fd=1``, the host with ``fd=0``: the first handshake fails —
    it must — and its ``LinkTimeout`` names the CAN FD frames heard and the ``fd`` option, where it said
    only "no handshake"."""
    group, port = _group()
    board_url = f"can://udp_multicast/{group}?port={port}&node={NODE}&fd=1"
    host_url = f"can://udp_multicast/{group}?port={port}&node={NODE}&fd=0"
    said = _first_handshake_failure(board_url, host_url)
    assert "CAN FD" in said and "fd=0" in said, said


def _first_handshake_failure(board_url: str, host_url: str) -> str:
    """The ``LinkTimeout`` of a host's first handshake at ``host_url`` with a board served at
    ``board_url`` (ends set up unlike: it must fail)."""
    config = ClientConfig(handshake=RetryPolicy(timeout_s=0.1, max_tries=8))
    with CanServer(Board(BoardConfig(n_units=1), WallClock()), board_url):
        client = BoardClient(host_url, config=config)
        try:
            with pytest.raises(LinkTimeout) as caught:
                client.connect(timeout=3.0)
        finally:
            client.close()
    return str(caught.value)


@pytest.mark.parametrize(
    "interface", ["virtual", pytest.param("udp_multicast", marks=pytest.mark.udp_multicast)]
)
def test_a_host_on_another_node_id_than_its_board_is_told_why_the_handshake_failed(interface):
    """The board served as node 3, the host set up for node 0: the first handshake fails — it must — and
    its ``LinkTimeout`` names the node the board's frames came from and the ``node`` option, where it said
    only "no handshake" (every frame of the board counted ``rx_ignored``)."""
    if interface == "virtual":
        channel, extra = f"node-mismatch-{random.randint(0, 1 << 30)}", ""
    else:
        group, port = _group()
        channel, extra = group, f"port={port}&"
    board_url = f"can://{interface}/{channel}?{extra}node=3"
    host_url = f"can://{interface}/{channel}?{extra}node=0"
    said = _first_handshake_failure(board_url, host_url)
    assert "node 3" in said and "node 0" in said and "node option" in said, said

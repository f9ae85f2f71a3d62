"""Hunt 7, area F: a misconfigured second board at this board's node id, on a bus across processes.

Both boards' frames carry the same arbitration ids, so the host's reassembler took both: ``hil run``
against two ``firmware-sim --can …&node=3`` saw the two boards' telemetry interleaved as one board —
577 "resets" with boot ids flipping back and forth, 104 re-arms, the run lost after 35 s — and nothing
named the cause. On ``udp_multicast`` each node is a socket of its own: the transport follows the first
sender it hears in its peer's direction and node id, and counts (``rx_other_sender``) and logs another's
frames, never merging them; a sender silent for :data:`PEER_HANDOVER_S` is succeeded by the next (a
restarted board is a new process, a new socket)."""

from __future__ import annotations

import logging
import time

import pytest
from can_support import multicast_url

from bench.child import firmware_sim, started
from hil.link.transports.can_bus import PEER_HANDOVER_S, CanTransport
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import Heartbeat, Hello, HelloReply

pytestmark = pytest.mark.udp_multicast


def _boot_ids(host: CanTransport, framer: Framer, seconds: float) -> list[int]:
    """Boot ids of the board frames ``host`` delivers within ``seconds`` (saying Hello every 0.2 s)."""
    deframer = Deframer()
    said: list[int] = []
    end = time.monotonic() + seconds
    hello_at = 0.0
    while time.monotonic() < end:
        if time.monotonic() >= hello_at:
            host.write(framer.encode(Hello())[1])
            hello_at = time.monotonic() + 0.2
        for event in deframer.feed(host.read(0.05)):
            if isinstance(event, Frame) and isinstance(event.message, (HelloReply, Heartbeat)):
                said.append(event.message.boot_id)
    return said


def test_a_second_board_on_the_node_is_counted_and_logged_never_merged(caplog):
    """Two firmware-sim boards at one node id on one udp_multicast group, a host in this process: every
    frame it delivers is one board's (one boot id), the other's are counted and logged."""
    url = multicast_url(node=3)
    spec = url.removeprefix("can://")
    board = firmware_sim("--units", "1", "--heartbeat-rate", "20", "--can", spec)
    with caplog.at_level(logging.WARNING), started(board) as one:
        assert one.first_line == url, one.said
        with CanTransport(url) as host:
            first = _boot_ids(host, Framer(), 1.0)
            with started(board) as two:
                assert two.first_line == url, two.said
                both = _boot_ids(host, Framer(), 2.0)
            counters = host.counters()
    assert first and both, (first, both)
    assert set(both) == set(first), (first, both)  # one board followed throughout: never the twin's
    assert counters["rx_other_sender"] > 0, counters
    said = caplog.text
    assert "rx_other_sender" in said and "node 3" in said, said


def test_a_board_restarted_on_the_bus_is_followed_after_its_predecessor_fell_silent():
    """The board killed and started again (a new process: a new socket): the host follows the new one
    once the old has been silent for PEER_HANDOVER_S, and counts none of it as a second board."""
    url = multicast_url(node=4)
    spec = url.removeprefix("can://")
    board = firmware_sim("--units", "1", "--heartbeat-rate", "20", "--can", spec)
    with CanTransport(url) as host:
        with started(board):
            before = _boot_ids(host, Framer(), 1.0)
        time.sleep(PEER_HANDOVER_S)
        with started(board):
            after = _boot_ids(host, Framer(), 1.5)
        counters = host.counters()
    assert before and after and not set(before) & set(after), (before, after)
    assert counters["rx_other_sender"] == 0, counters

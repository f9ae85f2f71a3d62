"""An end that closes its bus and opens it again — the board client's reconnection after its board stopped
answering or its bus failed — on python-can's ``udp_multicast``, where each node sends from a socket of its
own and its peer follows one sender at its node id (``rx_other_sender``). Before: the reopened end sent
from a new ephemeral port, so its peer took it for a second host at the same node id, dropped its frames
(its Hello among them) until the old socket had been silent for ``PEER_HANDOVER_S`` and logged "two hosts
configured with node id N?" at every reconnection. Now the reopened end sends from the port it had."""

from __future__ import annotations

import logging
import socket
import time

import hypothesis.strategies as st
import pytest
from can_support import multicast_url, read_until
from hypothesis import HealthCheck, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import Direction
from protocol.frame import Framer
from protocol.messages import Arm, Heartbeat, Hello

NODE = 3
pytestmark = pytest.mark.udp_multicast


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    before=st.integers(0, 4),
    gaps_s=st.lists(st.floats(0.0, 0.15), min_size=1, max_size=3),
    after=st.integers(1, 4),
)
def test_a_reopened_end_is_followed_at_once_never_taken_for_a_second_node(before, gaps_s, after, caplog):
    caplog.clear()
    url = multicast_url(node=NODE)
    framer = Framer()
    with CanTransport(url, sends=Direction.TO_HOST) as board, CanTransport(url) as host:
        with caplog.at_level(logging.WARNING, logger="hil.link.transports.can_bus"):
            sent = [framer.encode(Heartbeat())[1] for _ in range(before)]
            for wire in sent:
                host.write(wire)
            assert read_until(board, before, tries=40) == b"".join(sent)
            for gap in gaps_s:  # the client's reconnection, at drawn moments
                host.close()
                time.sleep(gap)
                host.open()
                sent = [framer.encode(Hello() if k == 0 else Arm())[1] for k in range(after)]
                for wire in sent:
                    host.write(wire)
                assert read_until(board, after, tries=40) == b"".join(sent)  # every one, at once
            assert board.counters()["rx_other_sender"] == 0
        said = " ".join(r.getMessage() for r in caplog.records)
        assert "second host" not in said, said


def test_a_second_host_is_still_told_apart_from_a_reopened_one():
    """The stable port is per transport: another host at the node id is still a second sender."""
    url = multicast_url(node=NODE)
    framer = Framer()
    with CanTransport(url, sends=Direction.TO_HOST) as board, CanTransport(url) as host:
        host.write(framer.encode(Hello())[1])
        assert read_until(board, 1, tries=40)
        host.close()
        host.open()
        with CanTransport(url) as twin:
            twin.write(framer.encode(Hello())[1])
            beat = framer.encode(Heartbeat())[1]
            host.write(beat)
            got = read_until(board, 1, tries=40)
        assert got == beat and board.counters()["rx_other_sender"] >= 1  # each of the twin's segments


def test_the_old_port_taken_meanwhile_opens_on_another():
    """The port the closed bus sent from taken by another socket before the reopen: the end opens on an
    ephemeral port (its peer follows it after PEER_HANDOVER_S, as a restarted node), never fails to open."""
    url = multicast_url(node=NODE)
    host = CanTransport(url).open()
    port = host._sender_port
    host.close()
    thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        thief.bind(("0.0.0.0", port))
        host.open()
        assert host._sender_port not in (0, port)
        host.write(Framer().encode(Hello())[1])
    finally:
        thief.close()
        host.close()


def test_the_board_s_can_server_takes_a_reopened_host_s_hello_at_once():
    """The board's CAN server (firmware-sim's, in its thread) and a host that reconnects: the Hello sent
    right after the reopen is taken within PEER_HANDOVER_S, and the server counts no second host."""
    url = multicast_url(node=NODE)
    framer = Framer()
    board = Board(BoardConfig(n_units=1, telemetry_rate_hz=20.0), WallClock())
    with CanServer(board, url) as server, CanTransport(url) as host:
        host.write(framer.encode(Hello())[1])
        assert read_until(host, 1, tries=40)
        host.close()
        host.open()
        host.write(framer.encode(Hello())[1])
        deadline = time.monotonic() + 0.4  # under PEER_HANDOVER_S: the old port's silence must not count
        replies = 0
        while time.monotonic() < deadline and not replies:
            replies = server.counters()["rx_frames"] - 1
            time.sleep(0.01)
        server.check()
        assert replies == 1 and server.counters()["rx_other_sender"] == 0

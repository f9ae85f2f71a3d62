"""A second node on the bus under this end's node id: two boards (or two hosts) configured alike.

Every such frame carries this end's own direction and node id, so the reassembler ignores it like the
loopback of this end's own frames (udp_multicast hears its own datagrams) — and a host then sees two
boards' telemetry interleaved as one board resetting over and over, with nothing naming the cause. The
transport tells its own frames' loopback from another node's (``rx_same_node``) and logs the clash."""

from __future__ import annotations

import logging
import random
import time

import can
import hypothesis.strategies as st
import pytest
from can_support import read_until, virtual_url
from hypothesis import given, settings

from bench.child import firmware_sim, started
from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.frame import Framer
from protocol.messages import Heartbeat, Hello

NODE = 5


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


def _board(url: str) -> CanServer:
    return CanServer(Board(BoardConfig(n_units=1, telemetry_rate_hz=50.0), WallClock()), url)


def test_two_boards_on_one_node_each_count_and_log_the_other(caplog):
    """Two boards served at one node id on one bus, a host talking to "its" board: each board counts the
    other's frames as another node using its id and logs it; the host, alone at its end, counts none. (The
    second board boots later: twins booted in the same millisecond say the very same frames, which no
    receiver can tell apart from its own.)"""
    url = virtual_url(node=NODE)
    framer = Framer()
    with caplog.at_level(logging.WARNING), _board(url) as one:
        time.sleep(0.2)
        with _board(url) as two, CanTransport(url) as host:
            host.write(framer.encode(Hello())[1])
            deadline = time.monotonic() + 20.0  # ends once both have counted: long only on a busy machine
            while time.monotonic() < deadline:
                host.write(framer.encode(Heartbeat())[1])
                host.read(0.02)
                if min(s.counters()["rx_same_node"] for s in (one, two)) >= 5:
                    break
            assert host.counters()["rx_same_node"] == 0
            for server in (one, two):
                assert server.counters()["rx_same_node"] >= 5, server.counters()
                server.check()
    assert f"another node uses node id {NODE}" in caplog.text


def test_a_second_host_on_the_board_s_node_is_counted_by_the_first():
    """Two hosts set to one board: each frame of the other host is counted by the first, never by the
    board (which takes both: it cannot tell them apart)."""
    url = virtual_url(node=NODE)
    with CanTransport(url) as first, CanTransport(url) as second:
        for n in range(4):
            second.write(Framer(n).encode(Heartbeat(time_ms=n))[1])
        assert read_until(first, 1, tries=5) == b""  # the other host's frames are not for a host
        assert first.counters()["rx_same_node"] == second.counters()["tx_segments_sent"] > 0


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_own_loopback_is_never_counted_however_much_of_it_is_lost_and_others_always_are(data):
    """A real virtual bus where a raw node plays the interface's loopback (the host's own segments back,
    in order, any of them lost, as a full socket buffer drops them) and another node at the host's id (its
    own heartbeats) interleaved anywhere: exactly the other node's segments are counted."""
    url = virtual_url(node=NODE, fd=data.draw(st.booleans(), label="fd"))
    fd = url.endswith("fd=1")
    raw = can.Bus(interface="virtual", channel=_channel(url), fd=True)
    try:
        with CanTransport(url) as host:
            framer = Framer()
            n_frames = data.draw(st.integers(1, 6), label="frames")
            for i in range(n_frames):
                host.write(framer.encode(Heartbeat(time_ms=i))[1])
            sent = [raw.recv(1.0) for _ in range(host.counters()["tx_segments_sent"])]
            assert all(m is not None for m in sent)
            echoes = [m for m in sent if data.draw(st.booleans(), label="echo heard")]
            impostor = CanTransport(url)  # only its segmenter: the other node's frames, same id and kind
            other = [
                s
                for i in range(data.draw(st.integers(0, 3), label="other frames"))
                # a board's heartbeat (its state, its boot id): no segment the same bytes as one of the
                # host's (state 0, boot id 0: a middle segment of COBS 0x01s in both would be)
                for s in impostor._segmenter.segment(
                    Framer(200).encode(Heartbeat(time_ms=10_000 + i, state=1, boot_id=0x5EED0000 + i))[1]
                )
            ]
            mixed = list(echoes)
            for s in other:
                mixed.insert(data.draw(st.integers(0, len(mixed)), label="where"), s)
            for m in mixed:
                raw.send(
                    can.Message(arbitration_id=m.arbitration_id, data=m.data, is_fd=fd, is_extended_id=False)
                )
            host.read(0.0)  # the virtual bus queued them all at send: one read takes every one
            assert host.counters()["rx_same_node"] == len(other)
            assert host.counters()["rx_frames"] == 0
    finally:
        raw.shutdown()


@pytest.mark.udp_multicast
def test_on_udp_multicast_own_frames_are_not_another_node_but_a_second_board_is():
    """Real processes: a board and a host exchange on udp_multicast, which loops every sender's datagrams
    back to it: neither counts its own as another node. A second firmware-sim at the same node id joins:
    it says another node uses its node id."""
    port = random.randint(40_000, 60_000)
    spec = f"udp_multicast/239.74.165.{random.randint(1, 254)}?port={port}&node={random.randint(1, 126)}"
    framer = Framer()
    argv = firmware_sim("--units", "1", "--telemetry-rate", "50", "--can", spec)
    with started(argv) as board, CanTransport(board.first_line) as host:
        host.write(framer.encode(Hello())[1])
        for _ in range(40):
            host.write(framer.encode(Heartbeat())[1])
            host.read(0.02)
        assert host.counters()["rx_frames"] > 0 and host.counters()["rx_ignored"] > 0  # own loopback
        assert host.counters()["rx_same_node"] == 0
        with started(argv) as twin:
            for _ in range(40):
                host.write(framer.encode(Heartbeat())[1])
                host.read(0.02)
            twin.stop()
        board.stop()
    assert "another node uses node id" in board.said and "another node uses node id" in twin.said
    assert "Traceback" not in board.said + twin.said

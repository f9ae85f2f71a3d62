"""The board's CAN server beside its path: its own process stalled (SIGSTOP/SIGCONT, a long pause) while
the host kept talking. The host's frames waited on the bus; when the server runs again it must take them
as heard *now* — the host never left — and only a host that really fell silent for the stall is gone."""

from __future__ import annotations

import random
import signal
import threading
import time

import hypothesis.strategies as st
import pytest
from can_support import virtual_url
from hypothesis import given, settings

from bench.child import firmware_sim, started
from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.base import HOST_SILENCE_S
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import LockstepClock
from protocol.frame import Framer
from protocol.messages import Heartbeat


@settings(max_examples=25, deadline=None)
@given(stall=st.floats(HOST_SILENCE_S + 0.01, 60.0), spoken=st.integers(0, 3))
def test_a_stalled_board_counts_the_host_present_when_its_frames_waited_on_the_bus(stall, spoken):
    """Lockstep: the board's clock runs on through a stall of ``stall`` s in which its loop did not, and
    the host wrote ``spoken`` frames meanwhile. With frames waiting, the host is present after the stall
    (never gone and back); with none, it was silent longer than HOST_SILENCE_S and is gone."""
    clock = LockstepClock(0.0)
    url = virtual_url(node=3)
    framer = Framer()
    server = CanServer(Board(BoardConfig(n_units=1), clock), url)
    try:
        with CanTransport(url) as host:
            host.write(framer.encode(Heartbeat())[1])
            server.pump(clock.now())
            assert server.take_in(0.5)
            assert server.stats.host_present
            clock.advance(stall)  # the server's process stopped; its board's clock is the wall's
            for _ in range(spoken):
                host.write(framer.encode(Heartbeat())[1])
            server.take_in(0.5 if spoken else 0.0)
            server.pump(clock.now())
            assert server.stats.host_present is bool(spoken), server.stats
            assert server.stats.host_gone == (0 if spoken else 1), server.stats
            assert server.stats.reconnects == 0, server.stats
    finally:
        server.close()


@pytest.mark.udp_multicast
def test_firmware_sim_stopped_and_continued_mid_stream_does_not_report_the_host_gone():
    """A real board process SIGSTOPped for 1.5 s (longer than HOST_SILENCE_S) while a host streams
    heartbeats on udp_multicast, then SIGCONTinued: its status says the host connected once and never
    left (the host's frames waited in the socket), and it keeps answering."""
    spec = (
        f"udp_multicast/239.74.164.{random.randint(1, 254)}?port={random.randint(40_000, 60_000)}"
        f"&node={random.randint(1, 126)}"
    )
    with started(firmware_sim("--units", "1", "--telemetry-rate", "50", "--can", spec)) as board:
        done = threading.Event()
        with CanTransport(board.first_line) as host:

            def talk() -> None:
                framer = Framer()
                while not done.is_set():
                    host.write(framer.encode(Heartbeat())[1])
                    time.sleep(0.02)

            talker = threading.Thread(target=talk, daemon=True)
            talker.start()
            try:
                time.sleep(0.4)
                board.proc.send_signal(signal.SIGSTOP)
                time.sleep(HOST_SILENCE_S + 0.5)
                board.proc.send_signal(signal.SIGCONT)
                time.sleep(0.4)
                host.read(0.0)
                before = host.counters()["rx_frames"]
                time.sleep(0.3)
                while host.read(0.05):
                    pass
                assert host.counters()["rx_frames"] > before  # the board runs and talks again
                assert board.stop() == 0
            finally:
                done.set()
                talker.join(timeout=2)
    said = board.said
    assert "host connected" in said and "host left" not in said.replace("host left 0 time(s)", ""), said
    assert "host connected again" not in said, said

"""A CAN bus that reports errors: error frames (the controller's report of a frame nobody acknowledged, a
bus-off, a bit-rate mismatch) and remote frames, heard on real python-can ``virtual`` buses among the
board's own frames. Each must be counted, logged (at a bounded rate) naming its class, and said when a
handshake times out — before, they were counted ``rx_error_frames`` and nothing else: both ends' logs
silent, and a host whose board was unplugged was told only "no handshake"."""

from __future__ import annotations

import itertools
import logging
import threading

import can
import hypothesis.strategies as st
import pytest
from can_support import read_until, virtual_url
from hypothesis import HealthCheck, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.board import BoardClient, ClientConfig
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import CanSegmenter, Direction
from protocol.errors import LinkTimeout
from protocol.frame import encode_frame
from protocol.messages import Telemetry
from protocol.reliable import RetryPolicy

NODE = 5
_seq = itertools.count()
CLASSES = {
    0x001: "transmit timeout",
    0x002: "arbitration lost",
    0x004: "controller problem",
    0x008: "protocol violation",
    0x010: "transceiver problem",
    0x020: "no acknowledgement",
    0x040: "bus off",
    0x080: "bus error",
    0x100: "controller restarted",
}


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


def _board_frame() -> tuple[bytes, list]:
    wire = encode_frame(Telemetry(time_ms=next(_seq), pulses_us=(1500,) * 8), next(_seq) & 0xFF)
    return wire, CanSegmenter(NODE, Direction.TO_HOST).segment(wire)


def _error_frame(classes: int) -> can.Message:
    """An error frame as SocketCAN hands it up: its id the error class bits, 8 bytes of details."""
    return can.Message(arbitration_id=classes, data=bytes(8), is_error_frame=True, is_extended_id=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    classes=st.lists(st.integers(0, 0x1FF), min_size=1, max_size=40),
    remote=st.integers(0, 3),
    data=st.data(),
)
def test_error_and_remote_frames_are_counted_logged_by_class_and_never_touch_the_board_s_frames(
    classes, remote, data, caplog
):
    caplog.clear()
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with CanTransport(url) as host:
            wire, segments = _board_frame()
            hostile = [_error_frame(c) for c in classes] + [
                can.Message(arbitration_id=segments[0].arbitration_id, is_remote_frame=True, dlc=8)
                for _ in range(remote)
            ]
            # the trouble at drawn moments among the frame's segments
            order = data.draw(st.permutations(range(len(hostile) + len(segments))))
            queue = hostile + [
                can.Message(arbitration_id=s.arbitration_id, data=s.data, is_extended_id=False)
                for s in segments
            ]
            in_order = iter(queue[len(hostile) :])
            for i in order:  # the segments keep their own order; the hostile frames fall between them
                raw.send(next(in_order) if i >= len(hostile) else queue[i])
            with caplog.at_level(logging.WARNING, logger="hil.link.transports.can_bus"):
                got = read_until(host, 1)
                while host.read(0.0):
                    pass
            assert got == wire  # the board's frame whole, nothing else
            assert host.counters()["rx_error_frames"] == len(hostile)
            said = [r.getMessage() for r in caplog.records if "more dropped since" not in r.getMessage()]
            errors = [m for m in said if "CAN error frame" in m]
            remotes = [m for m in said if "remote frame" in m]
            assert len(errors) == 1 and len(remotes) == (1 if remote else 0), said  # once a second
            logged = classes[next(i for i in order if i < len(classes))]  # the first error frame sent
            first = [name for bit, name in CLASSES.items() if logged & bit] or ["unspecified"]
            assert all(name in errors[0] for name in first), errors
            instead = host.heard_instead()
            assert "error frames" in instead and "acknowledg" in instead, instead
            for bit, name in CLASSES.items():
                n = sum(1 for c in classes if c & bit)
                assert (f"{name} x{n}" in instead) == (n > 0), instead
            assert ("remote frame" in instead) == (remote > 0), instead
    finally:
        raw.shutdown()


def test_a_host_whose_bus_reports_only_errors_is_told_so_when_the_handshake_times_out():
    """No board on the bus: every frame the host sends goes unacknowledged and its controller reports it
    (an ACK error frame each). Before: "no handshake within 1.5 s", nothing else."""
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    config = ClientConfig(handshake=RetryPolicy(timeout_s=0.1, max_tries=8))
    client = BoardClient(url, config=config)
    done = threading.Event()

    def controller() -> None:
        """The host's controller, as it were: each frame the host sends draws an ACK error frame."""
        while not done.is_set():
            if raw.recv(0.02) is not None:
                raw.send(_error_frame(0x020))

    reporter = threading.Thread(target=controller, daemon=True)
    reporter.start()
    try:
        with pytest.raises(LinkTimeout) as caught:
            client.connect(timeout=1.5)
    finally:
        done.set()
        reporter.join(2.0)
        client.close()
        raw.shutdown()
    said = str(caught.value)
    assert "error frames (no acknowledgement x" in said and "unplugged" in said, said


def test_the_board_s_can_server_logs_the_error_frames_it_hears(caplog):
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with caplog.at_level(logging.WARNING, logger="hil.link.transports.can_bus"):
            server = CanServer(Board(BoardConfig(n_units=1), WallClock()), url)  # its loop: take_in here
            try:
                raw.send(_error_frame(0x040))
                for _ in range(50):
                    server.take_in(0.02)
                    if server.counters()["rx_error_frames"]:
                        break
            finally:
                server.close()
        assert server.counters()["rx_error_frames"] == 1
        assert any("CAN error frame (bus off)" in r.getMessage() for r in caplog.records)
    finally:
        raw.shutdown()

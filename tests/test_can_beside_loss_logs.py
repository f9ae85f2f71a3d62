"""Frames a CAN end loses are logged, not only counted, at the bounded rate of its other drops.

Before, ``rx_malformed``, ``rx_incomplete`` and ``rx_spliced`` rose in the counters and nothing said so in
either end's log (only ``rx_same_node`` and the transmit drops were logged): a bus that loses frames — a
noisy cable, a second sender on the board's ids — was silent. Now each kind is logged at most once a
second, saying how many, and how many went unlogged since."""

from __future__ import annotations

import logging

import can
import hypothesis.strategies as st
from can_support import virtual_url
from hypothesis import HealthCheck, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import CanId, CanSegmenter, Direction, Priority
from protocol.frame import Framer
from protocol.messages import Telemetry

NODE = 5
_KINDS = ("malformed", "incomplete", "spliced")


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


def _losses(kind: str, sends: Direction, n: int) -> list[can.Message]:
    """CAN frames, from a sender in direction ``sends`` at ``NODE``, that cost its receiver ``n`` frames of
    ``kind`` (and nothing else of the three)."""
    segmenter = CanSegmenter(NODE, sends)
    framer = Framer()
    out = []

    def wire(i: int) -> bytes:
        return framer.encode(Telemetry(time_ms=i, pulses_us=(1500 + i,) * 8))[1]

    for i in range(n):
        if kind == "malformed":  # one byte: never a segment
            arb = CanId(Priority.STATUS, sends, NODE).value
            out.append(can.Message(arbitration_id=arb, data=b"\x01", is_extended_id=False))
        elif kind == "incomplete":  # a frame's last segment lost; the next frame's (whole) ends it
            segs = segmenter.segment(wire(2 * i))
            out += [_msg(s) for s in segs[:-1]]
            out += [_msg(s) for s in segmenter.segment(wire(2 * i + 1))]
        else:  # a frame loses its last segment, the next three are lost whole, the fourth its head
            first = segmenter.segment(wire(10 * i))
            for k in range(3):
                segmenter.segment(wire(10 * i + 1 + k))
            fifth = segmenter.segment(wire(10 * i + 5))
            assert len(first) == len(fifth)
            out += [_msg(s) for s in first[:-1]] + [_msg(fifth[-1])]
            # The receiver starts again from the fifth's segment: the next frame on the id gives it up
            # (one more incomplete, see _expected).
    return out


def _expected(counts: dict[str, int]) -> dict[str, int]:
    """What ``_losses`` of each kind, sent in ``_KINDS`` order, count: a splice leaves the newest frame's
    last segment pending, which the next splice's first segment gives up."""
    return {**counts, "incomplete": counts["incomplete"] + max(counts["spliced"] - 1, 0)}


def _msg(seg) -> can.Message:
    return can.Message(arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False)


def _lines(caplog, kind: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if f"(rx_{kind})" in r.getMessage()]


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    counts=st.fixed_dictionaries({kind: st.integers(0, 40) for kind in _KINDS}),
    sends=st.sampled_from(list(Direction)),
)
def test_each_kind_of_lost_frame_is_logged_once_within_a_second_with_its_count(caplog, counts, sends):
    """Any number of each loss, at either end (a host, or the board's side as firmware-sim's CanServer
    opens it), on a real virtual bus: the counter holds every one, and each kind that rose is logged —
    once within the second, however many (bounded: a flood is one line, not one per frame)."""
    caplog.clear()
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    peer = Direction.TO_BOARD if sends is Direction.TO_HOST else Direction.TO_HOST
    try:
        with caplog.at_level(logging.WARNING), CanTransport(url, sends=sends) as end:
            for kind in _KINDS:
                for msg in _losses(kind, peer, counts[kind]):
                    raw.send(msg)
            for _ in range(20):
                if not end.read(0.0) and end.read(0.01) == b"":
                    break
            counters = end.counters()
    finally:
        raw.shutdown()
    expected = _expected(counts)
    for kind in _KINDS:
        assert counters[f"rx_{kind}"] == expected[kind], counters
        lines = _lines(caplog, kind)
        assert len(lines) == (1 if expected[kind] else 0), lines
        if lines:
            assert lines[0].split(": ", 1)[1].startswith("1 ")  # the first is logged at once, counted


def test_a_flood_says_how_many_went_unlogged(caplog, monkeypatch):
    """After the second, the next line says how many of that kind were not logged in between."""
    import hil.link.transports.can_bus as can_bus

    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with caplog.at_level(logging.WARNING), CanTransport(url) as host:
            for msg in _losses("malformed", Direction.TO_HOST, 50):
                raw.send(msg)
            host.read(0.01)
            monkeypatch.setattr(can_bus, "_LOG_EVERY_S", 0.0)
            for msg in _losses("malformed", Direction.TO_HOST, 1):
                raw.send(msg)
            host.read(0.01)
    finally:
        raw.shutdown()
    lines = _lines(caplog, "malformed")
    assert len(lines) == 2 and "(49 more since)" in lines[1], lines


def test_the_board_s_can_server_logs_what_it_loses(caplog):
    """firmware-sim's CAN server, serving in its thread, logs the host's frames it could not assemble."""
    url = virtual_url(node=NODE)
    board = Board(BoardConfig(n_units=1, telemetry_rate_hz=50.0), WallClock())
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with caplog.at_level(logging.WARNING), CanServer(board, url) as server:
            server.start()
            for kind in _KINDS:
                for msg in _losses(kind, Direction.TO_BOARD, 3):
                    raw.send(msg)
            expected = _expected(dict.fromkeys(_KINDS, 3))
            for _ in range(100):
                if all(server.counters()[f"rx_{k}"] >= expected[k] for k in _KINDS):
                    break
                raw.recv(0.01)
            server.check()
            assert all(server.counters()[f"rx_{k}"] == expected[k] for k in _KINDS), server.counters()
    finally:
        raw.shutdown()
    for kind in _KINDS:
        assert len(_lines(caplog, kind)) == 1

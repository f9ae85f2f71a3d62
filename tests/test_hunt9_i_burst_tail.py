"""A burst of hostile CAN frames — 10 000 at once, then quiet — on a real python-can ``virtual`` bus. Each
drop is counted, and the log, held to a line a second per kind, must still come to say how many: before,
the rest of a burst was said only with the next drop of its kind, so a burst followed by quiet left one
line saying "1 ... dropped" and the log told of one lost frame where there were thousands."""

from __future__ import annotations

import logging
import re
import time

import can
import pytest
from can_support import virtual_url

from hil.link.transports.can_bus import CanTransport
from protocol.can import CanId, Direction, Priority

NODE = 5


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


def _hostile(kind: str, i: int) -> can.Message:
    if kind == "malformed":  # one byte on the board's id: never a segment
        arb = CanId(Priority.STATUS, Direction.TO_HOST, NODE).value
        return can.Message(arbitration_id=arb, data=bytes([i & 0xFF]), is_extended_id=False)
    return can.Message(arbitration_id=0x020, data=bytes(8), is_error_frame=True, is_extended_id=False)


def _said(caplog, url: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith(url)]


@pytest.mark.parametrize("kind", ["malformed", "error_frames"])
@pytest.mark.parametrize("burst", [2, 10_000])
def test_a_burst_then_quiet_is_said_whole_within_about_a_second(kind, burst, caplog):
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    try:
        with (
            caplog.at_level(logging.WARNING, logger="hil.link.transports.can_bus"),
            CanTransport(url) as host,
        ):
            for i in range(burst):
                raw.send(_hostile(kind, i))
            while host.counters()[f"rx_{kind}"] < burst:  # the virtual bus queued them all at send
                assert host.read(0.01) == b""
            first = _said(caplog, url)
            assert len(first) == 1, first  # at once: the first; the rest held back by the rate
            end = time.monotonic() + 1.5
            while time.monotonic() < end and len(_said(caplog, url)) < 2:
                assert host.read(0.05) == b""  # quiet: nothing else arrives
            said = _said(caplog, url)
    finally:
        raw.shutdown()
    assert len(said) == 2, said
    more = re.search(r"(\d+) more dropped since", said[1])
    assert more is not None and int(more.group(1)) == burst - 1, said

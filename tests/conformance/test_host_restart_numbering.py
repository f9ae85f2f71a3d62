"""A restarted host numbers its frames from 0 again, and its first frame is a ``Hello``: the board counts
the step to that ``Hello`` as lost frames (``Telemetry.seq_gaps``) — for every target. Frames really lost
after the ``Hello`` still count.

The C firmware's deframer once counted the jump from the old host's last number to the new host's
``Hello`` as up to 255 lost frames at every restart of ``hil run`` against a running board (the Python
emulator's since 0f6f44a did not; docs/protocol.md, "Counters").

Drawn: how many frames the old host sent (so its last number, and the step to 0), where the new host's
numbering starts, and whether the new host's ``Hello`` repeats the old host's last number (a step of 0).
"""

from __future__ import annotations

import random

from conformance.host import heartbeat
from protocol.frame import Framer
from protocol.messages import Telemetry


def _gaps(host) -> int:
    """The board's ``seq_gaps`` in its next Telemetry."""
    report = host.wait_type(Telemetry, 1.0)
    assert isinstance(report, Telemetry)
    return report.seq_gaps


def test_a_restarted_hosts_hello_is_no_gap(target, host):
    rng = random.Random(0x4E57)
    host.handshake()
    for restart in range(4):
        for i in range(rng.randint(5, 120)):  # the old host's traffic: its numbers run on
            host.send(heartbeat())
            if i % 8 == 7:
                host.poll(0.01)  # in a host's pace: a burst would overflow the board's receive ring
        host.poll(0.05)
        gaps = _gaps(host)
        last = (host.framer.next_seq - 1) & 0xFF
        first = rng.choice([0, 0, last, rng.randint(0, 255)])  # from 0, the same number, anywhere
        host.framer = Framer(first)  # the new host's framer: a process of its own, numbering afresh
        host.deframer.reset()
        host.handshake()
        host.send(heartbeat())
        host.poll(0.05)
        assert _gaps(host) == gaps, f"restart {restart}: {last} then Hello at {first}"
    # numbering that does skip after a Hello is still counted: 3 frames lost
    gaps = _gaps(host)
    host.framer = Framer((host.framer.next_seq + 3) & 0xFF)
    host.send(heartbeat())
    host.poll(0.05)
    assert _gaps(host) == gaps + 3

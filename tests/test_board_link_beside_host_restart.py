"""A host restarted against a board that kept running: the new host numbers its frames from 0 again.

What the board does with the new numbering (docs/protocol.md, "Reliable commands", "Counters"):

* its answer cache — the only place a sequence number decides anything on the board — is cleared by the
  new host's ``Hello`` (the firmware's ``on_hello`` does the same), so a command of the new host reusing a
  sequence number of the old one is executed, never answered from the cache;
* its deframer counted the jump from the old host's last number to the new host's ``Hello`` as frames
  lost (``Telemetry.seq_gaps``, the host's ``LinkStats.board_seq_gaps``): up to 255 frames the new host
  never sent, at every restart. A ``Hello`` begins its sender's numbering afresh: the step to one is no
  longer counted, and a restart costs the board's counters nothing.
"""

from __future__ import annotations

import time

import hypothesis.strategies as st
import serial
from hypothesis import given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.pty_server import PtyServer
from hil.link.board import BoardClient
from hil.timing.clock import WallClock
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import SCHEMA_HASH, Arm, BoardState, Disarm, Heartbeat, Hello

CFG = BoardConfig(n_units=1, telemetry_rate_hz=100.0)
HELLO = Hello(schema_hash=SCHEMA_HASH, manufacturer="tests", model="old host")


def _old_host(path: str, frames: int, arm: bool) -> None:
    """A host that handshakes, sends ``frames`` more frames (an Arm among them if ``arm``) and is killed:
    its port closed without a word more."""
    framer = Framer()
    with serial.Serial(path, timeout=0.05) as port:
        port.write(framer.encode(HELLO)[1])
        for k in range(frames):
            message = Arm() if arm and k == frames // 2 else Heartbeat(time_ms=k)
            port.write(framer.encode(message)[1])
            if k % 32 == 0:
                time.sleep(0.005)
        port.flush()
        time.sleep(0.05)


@settings(max_examples=6, deadline=None)
@given(frames=st.integers(1, 600), arm=st.booleans())
def test_a_restarted_host_costs_no_sequence_gaps_and_its_commands_are_executed(frames, arm):
    """Real pty, pyserial and the board's pty server: an old host sends ``frames`` frames and dies; a new
    host (the board client: a fresh framer from 0) connects, arms and disarms. Its Arm — which may reuse
    the old host's Arm's sequence number — is executed and ACKed, and the board's counters, read in its
    telemetry, report no frame lost: nothing was."""
    with PtyServer(Board(CFG, WallClock())) as server:
        time.sleep(0.2)  # past the board's boot
        _old_host(server.path, frames, arm)
        with server.lock:
            before = server.board.link.deframer.counters.seq_gaps
        assert before == 0  # one host, nothing lost
        client = BoardClient(server.path)
        with client:
            client.arm()
            assert client.state is BoardState.ARMED
            client.disarm()
            end = time.monotonic() + 2.0
            while client.telemetry is None or client.telemetry.state is not BoardState.DISARMED:
                client.service()
                time.sleep(0.01)
                assert time.monotonic() < end
            stats = client.stats()
        assert stats.board_seq_gaps == 0, stats
        assert stats.acked >= 3 and stats.failed == 0 and stats.nacked == 0  # Hello, Arm, Disarm


def test_a_hello_begins_its_sender_s_numbering_afresh_on_the_board_s_deframer():
    """Sans-IO, the board's own deframer: the step to a Hello (any sequence number) is neither a gap nor
    a duplicate; every other step still is."""
    board = Board(CFG, WallClock())
    deframer = board.link.deframer
    old = Framer(first_seq=200)
    wire = b"".join(old.encode(Heartbeat(time_ms=k))[1] for k in range(10))
    new = Framer()
    wire += new.encode(HELLO)[1] + new.encode(HELLO, seq=0)[1]  # a Hello and its retry
    wire += new.encode(Disarm())[1]
    new.encode(Heartbeat())  # a frame lost on the way
    wire += new.encode(Heartbeat())[1]
    events = deframer.feed(wire)
    assert len(events) == 14 and all(isinstance(e, Frame) for e in events)
    assert (deframer.counters.seq_gaps, deframer.counters.duplicates) == (1, 0)  # the lost Heartbeat
    plain = Deframer()  # a deframer not told about Hello (the protocol's default) counts every step
    plain.feed(wire)
    assert (plain.counters.seq_gaps, plain.counters.duplicates) == (1 + (0 - 209) % 256 - 1, 1)

"""A board that resets while the host stays on the link numbers its frames from 0 again: the host's count of
the board's lost frames (``LinkStats.seq_gaps``, the ground station's "sequence gaps") took the jump from
the old boot's last number to the new boot's first as up to 255 frames lost, at every reset — frames that
never existed. The boot id the new boot says in its first frames now takes that step back; losses within a
boot are still counted."""

from __future__ import annotations

import time

import hypothesis.strategies as st
from hypothesis import given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.pty_server import PtyServer
from hil.link.board import BoardClient, BoardResetEvent
from hil.timing.clock import WallClock
from protocol.messages import ResetCause


@settings(max_examples=4, deadline=None)
@given(before=st.floats(0.05, 0.8), resets=st.integers(1, 2))
def test_a_board_reset_under_a_live_link_costs_no_sequence_gaps(before, resets):
    """Real pty, pyserial, the board's pty server and the board client with its reader thread: the board is
    reset ``resets`` times at a drawn moment of its session; each reset is reported, and the host counts no
    board frame lost (none was: the pty loses nothing)."""
    board = Board(BoardConfig(n_units=1, telemetry_rate_hz=100.0), WallClock())
    with PtyServer(board) as server:
        time.sleep(0.2)
        client = BoardClient(server.path)
        with client:
            client.start()
            seen = 0
            for _ in range(resets):
                time.sleep(before)
                with server.lock:
                    board.reset(ResetCause.EXTERNAL)
                end = time.monotonic() + 3.0
                while seen < resets and time.monotonic() < end:
                    seen += sum(isinstance(e, BoardResetEvent) for e in client.drain_events())
                    time.sleep(0.02)
            time.sleep(0.3)  # the new boot's telemetry after its handshake
            stats = client.stats()
        assert stats.counters.resets == resets, stats.counters
        assert stats.seq_gaps == 0 and stats.duplicates == 0, (stats.seq_gaps, stats.duplicates)

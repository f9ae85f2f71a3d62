"""The pty wrapper (firmware_sim.servers.pty_server) through real ptys and pyserial: hosts that vanish (EIO),
a host that does not read, the symlink, and errors in the serving thread."""

from __future__ import annotations

import time

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.pty_server import PtyServer
from hil.timing.clock import WallClock
from protocol.errors import LinkError
from protocol.messages import BoardState, Telemetry

CFG = BoardConfig(n_units=2, telemetry_rate_hz=200.0)


def test_without_holding_the_slave_eio_is_survived_and_the_host_can_return():
    with PtyServer(Board(CFG, WallClock()), hold_slave=False) as server:
        # A silence this long is never what tells a departure below (each is waited for at most a sixth of
        # it), however late a loaded machine runs the server's thread: only EIO can.
        server.presence.silence_s = 60.0
        time.sleep(0.1)  # nobody on the slave yet: the master reads EIO
        assert not server.stats.host_present and server.stats.host_gone == 0  # never there: never gone
        for _ in range(2):
            host = SerialHost(server.path)
            reply = host.handshake()
            assert reply.state == BoardState.DISARMED
            host.keepalive = heartbeat
            assert host.wait_type(Telemetry, 1.0).state == BoardState.DISARMED
            assert server.stats.host_present
            host.close()
            gone_by = time.monotonic() + server.presence.silence_s / 6
            while server.stats.host_present:  # EIO: gone at once (~ms), not after a silence
                assert time.monotonic() < gone_by, "the host's departure was not noticed at once"
                time.sleep(0.01)
        stats = server.stats
        assert (stats.host_gone, stats.reconnects) == (2, 1)  # noticed each departure and the return
        assert stats.frames_in >= 4 and stats.frames_out > stats.frames_in and stats.errors == 0
        server.check()
        assert server._thread is not None and server._thread.is_alive()


def test_a_host_that_does_not_read_costs_dropped_output_not_memory():
    board = Board(CFG.replace(telemetry_rate_hz=1000.0), WallClock())
    with PtyServer(board) as server:
        host = SerialHost(server.path)
        host.handshake()
        time.sleep(1.0)  # ~100 kB of telemetry that nobody reads
        assert len(server._out) <= 4096
        assert server.stats.dropped_out > 0
        host.port.reset_input_buffer()
        host.keepalive = heartbeat
        tel = host.wait_type(Telemetry, 1.0)
        with server.lock:
            uptime = board.uptime_ms()
        assert uptime - tel.time_ms < 300  # fresh telemetry after the backlog, not minutes-old data
        host.close()


def test_symlink_follows_the_pty_and_a_real_file_is_not_replaced(tmp_path):
    link = tmp_path / "board"
    link.symlink_to("/nonexistent-old-target")
    server = PtyServer(Board(CFG, WallClock()), link=link)
    assert link.resolve() == type(link)(server.path).resolve()
    server.close()
    assert not link.is_symlink()
    real = tmp_path / "file"
    real.write_text("keep me")
    with pytest.raises(LinkError, match="not a symlink"):
        PtyServer(Board(CFG, WallClock()), link=real)
    assert real.read_text() == "keep me"


def test_serve_for_a_duration_returns():
    server = PtyServer(Board(CFG, WallClock()))
    t0 = time.monotonic()
    server.serve(duration=0.2)
    assert 0.19 <= time.monotonic() - t0 < 1.0
    assert server.board.now >= 0.2
    server.close()
    server.close()  # idempotent


def test_an_error_in_the_serving_thread_is_raised_not_swallowed():
    board = Board(CFG, WallClock())
    server = PtyServer(board).start()

    def broken(now=None):
        raise RuntimeError("boom")

    with server.lock:
        board.step = broken  # type: ignore[method-assign]
    time.sleep(0.2)
    with pytest.raises(LinkError, match="boom"):
        server.close()

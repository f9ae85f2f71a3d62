"""The emulator transports: emu:// (in-process board on the host's clock) and spawn://firmware-sim (a real
process on a real pty, stopped on close and when its host dies)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from firmware_sim.servers.transports import EmulatorTransport, SpawnTransport
from hil.link.transports import create_transport, open_transport
from hil.timing.clock import LockstepClock, WallClock
from protocol.errors import LinkError, TransportError
from protocol.frame import Frame, Framer, decode_stream
from protocol.messages import SCHEMA_HASH, Heartbeat, Hello, HelloReply, Log


def messages(data: bytes) -> list[object]:
    return [e.message for e in decode_stream(data) if isinstance(e, Frame)]


def alive(pid: int) -> bool:
    """Running (a zombie left to a non-reaping init counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def wait_gone(pid: int, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if not alive(pid):
            return True
        time.sleep(0.02)
    return False


# =========================================================================== emu://
def test_lockstep_reads_never_wait_and_the_board_follows_the_clock():
    clock = LockstepClock()
    with EmulatorTransport("emu://?units=2", clock) as transport:
        start = time.perf_counter()
        assert transport.read(1.0) == b""  # in reset (boot takes 50 ms of board time): nothing, at once
        assert time.perf_counter() - start < 0.1
        clock.advance(0.0605)
        booted = messages(transport.read(1.0))
        assert [type(m) for m in booted] == [Log, Heartbeat]
        assert transport.board.now == pytest.approx(0.0605)
        transport.write(Framer().encode(Hello(schema_hash=SCHEMA_HASH))[1])
        assert transport.read(0) == b""  # handled on the board's next main-loop tick, 1 ms on
        clock.advance(0.0005)
        assert any(isinstance(m, HelloReply) for m in messages(transport.read(0)))
        assert transport.next_wake() > clock.now()


def test_realtime_reads_wait_for_the_boards_output():
    # A heartbeat every 2 s: the board's next output but for the reply is the next heartbeat, seconds
    # away, so "answered at once" stays apart from it (and from the read's timeout) on a loaded machine.
    with EmulatorTransport("emu://?units=2&heartbeat_rate=0.5", WallClock()) as transport:
        start = time.monotonic()
        got = b""
        while not any(isinstance(m, Heartbeat) for m in messages(got)):
            got += transport.read(1.0)
        assert time.monotonic() - start < 0.5  # the boot heartbeat at ~50 ms, not a 1 s timeout
        start = time.monotonic()
        transport.write(Framer().encode(Hello(schema_hash=SCHEMA_HASH))[1])
        reply = transport.read(5.0)
        assert any(isinstance(m, HelloReply) for m in messages(reply))
        # answered on the board's next tick (ms; ~20 ms seen on a loaded 2-core machine), not at its next
        # heartbeat (~2 s on) or the read's timeout (5 s)
        assert time.monotonic() - start < 0.5


def test_emu_options_are_firmware_sims():
    transport = EmulatorTransport(
        "emu://?units=3&frame-rate=400&telemetry_rate=100&ppm=1&stall=5:2", LockstepClock()
    )
    cfg = transport.board.config
    assert (cfg.n_units, cfg.frame_rate_hz, cfg.telemetry_rate_hz, cfg.ppm) == (3, 400.0, 100.0, True)
    assert [(s.start, s.duration) for s in transport.board.faults.stalls] == [(5.0, 2.0)]
    with pytest.raises(TransportError, match="unrecognized arguments: --bogus"):
        create_transport("emu://?bogus=1")
    with pytest.raises(TransportError, match="'link' is not available"):
        create_transport("emu://?link=/tmp/board")
    with pytest.raises(TransportError, match="'can' is not available"):
        create_transport("emu://?can=virtual/x")
    with pytest.raises(TransportError, match="ppm='maybe' is not a boolean"):
        create_transport("emu://?ppm=maybe")
    with pytest.raises(TransportError, match="invalid int value"):
        create_transport("emu://?units=four")
    with pytest.raises(TransportError, match="only options"):
        create_transport("emu://board/x")
    with pytest.raises(TransportError, match="--units: 99 is outside 1..8"):
        open_transport("emu://?units=99")


def test_the_board_keeps_running_across_a_reopen():
    clock = LockstepClock()
    transport = EmulatorTransport("emu://?units=1", clock).open()
    board = transport.board
    clock.advance(1.0)
    transport.read(0)
    transport.close()
    clock.advance(1.0)
    transport.open()
    transport.read(0)
    assert transport.board is board and board.now == pytest.approx(2.0) and len(board.resets) == 1


def test_binding_another_clock_is_refused():
    transport = EmulatorTransport("emu://", LockstepClock())
    transport.bind_clock(transport.clock)  # the same one: fine
    with pytest.raises(TransportError, match="another clock"):
        transport.bind_clock(WallClock())


# =========================================================================== spawn://
def test_spawned_firmware_sim_serves_a_pty_and_stops_on_close(tmp_path):
    link = tmp_path / "board"
    transport = open_transport(f"spawn://firmware-sim?units=3&link={link}")
    assert isinstance(transport, SpawnTransport)
    pid = transport.pid
    assert pid is not None and alive(pid)
    assert link.is_symlink() and os.path.realpath(link) == os.path.realpath(transport.device)
    got = b""
    for _ in range(50):
        transport.write(Framer().encode(Hello(schema_hash=SCHEMA_HASH))[1])  # until it has booted
        got += transport.read(0.05)
        replies = [m for m in messages(got) if isinstance(m, HelloReply)]
        if replies:
            break
    assert replies and replies[0].n_units == 3
    transport.close()
    assert wait_gone(pid, 1.0)
    assert not link.exists()  # firmware-sim ended cleanly on SIGTERM (it removes its symlink)
    transport.close()  # idempotent


def test_a_spawned_board_dies_with_its_host_even_after_sigkill():
    host = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\n"
            "from hil.link.transports import open_transport\n"
            "t = open_transport('spawn://firmware-sim?units=1')\n"
            "print(t.pid, flush=True)\n"
            "time.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert host.stdout is not None
        child = int(host.stdout.readline())
        assert alive(child)
        host.send_signal(signal.SIGKILL)  # no close(), no atexit: only the kernel can tell the child
        host.wait(5)
        assert wait_gone(child), "firmware-sim outlived its host"
    finally:
        host.kill()
        host.wait()


def test_a_board_that_fails_to_start_is_an_error_quoting_its_message():
    start = time.monotonic()
    with pytest.raises(TransportError, match=r"exited with status 2.*--units: 99 is outside 1..8"):
        open_transport("spawn://firmware-sim?units=99")
    assert time.monotonic() - start < 5.0
    with pytest.raises(TransportError, match="only spawn://firmware-sim"):
        create_transport("spawn://other-program")
    with pytest.raises(TransportError, match="unrecognized arguments"):
        create_transport("spawn://firmware-sim?frame_rat=400")
    refused = r"start_timeout='soon' must be a number of seconds in \(0, 3600\]"
    with pytest.raises(TransportError, match=refused):
        create_transport("spawn://firmware-sim?start_timeout=soon")


def test_a_dead_board_process_is_a_vanished_port_and_reopening_starts_another():
    transport = open_transport("spawn://firmware-sim?units=1")
    try:
        first = transport.pid
        assert first is not None
        os.kill(first, signal.SIGKILL)
        with pytest.raises(LinkError):
            for _ in range(100):
                transport.read(0.05)
        transport.close()
        transport.open()
        assert transport.pid not in (None, first) and alive(transport.pid)
    finally:
        transport.close()

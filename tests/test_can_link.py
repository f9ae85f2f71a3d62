"""The whole link over CAN: the board client on a can:// transport against the emulated board served on a
python-can bus — in-process on the ``virtual`` interface, and in another process (``firmware-sim --can``)
over ``udp_multicast``."""

from __future__ import annotations

import itertools
import os
import random
import subprocess
import sys
import time

import pytest

from bench.child import firmware_sim, started
from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.board import BoardClient
from hil.timing.clock import WallClock
from protocol.errors import LinkError
from protocol.messages import ActuatorSetpoint, BoardState, UnitSetpoint

ROTOR = 1
_channels = itertools.count()


def exchange(url: str, units: int, lossless: bool = True) -> BoardClient:
    """Over any transport (a pty path, a ``can://`` URL): handshake, arm, setpoints until the rotor pulse
    follows them, disarm; returns the closed client. ``lossless=False`` for a bus that may drop a CAN frame
    (udp_multicast is UDP: a receive buffer that overflows while a loaded machine keeps the reader off the
    core drops datagrams), where a frame that lost a segment must be counted, never delivered."""
    client = BoardClient(url)
    with client:
        assert client.info is not None and client.info.n_units == units
        client.start()
        client.arm()
        widths: list[int] = []
        for speed in (150.0, 450.0):
            sp = ActuatorSetpoint(units=tuple(UnitSetpoint(0.0, speed) for _ in range(units)))
            end = time.monotonic() + 2.0
            floor = widths[-1] if widths else 1000  # each speed is faster: its pulse must be wider
            while True:
                client.send_setpoint(sp)
                time.sleep(0.02)
                client.service()
                tel = client.telemetry
                # A failsafe's (or a re-armed board's first) pulses are not the setpoint's.
                if tel is not None and tel.state is BoardState.ARMED and tel.pulses_us[ROTOR] > floor:
                    widths.append(tel.pulses_us[ROTOR])
                    break
                if client.state is BoardState.FAILSAFE:
                    # The host went quiet past the board's link timeout (a long test process's garbage
                    # collection, a loaded machine: CI saw it once) and the board failed safe, as it must:
                    # re-arm, as a host's run does, and give the setpoint its time again.
                    client.arm()
                    end = time.monotonic() + 2.0
                assert time.monotonic() < end, "the rotor pulse did not follow the setpoint"
        assert 1000 < widths[0] < widths[1] <= 2000
        client.disarm()
        assert client.state is BoardState.DISARMED
        client.stop()  # every frame the reader took from the bus has been fed to the session now
        stats = client.stats()
        assert stats.bad_frames_total == 0 and stats.failed == 0
        if "rx_frames" in stats.transport:  # a CAN bus's reassembly: each frame it completed was taken whole
            assert stats.transport["rx_frames"] == stats.frames_in
            assert stats.transport["rx_spliced"] == 0 and stats.transport["rx_malformed"] == 0
            if lossless:
                assert stats.transport["rx_incomplete"] == 0
    return client


@pytest.mark.parametrize("fd", [False, True])
def test_the_exchange_over_a_virtual_bus(fd):
    channel = f"can-link-{os.getpid()}-{next(_channels)}"
    url = f"can://virtual/{channel}?node=9&fd={int(fd)}"
    board = Board(BoardConfig(n_units=4, telemetry_rate_hz=50.0), WallClock())
    with CanServer(board, url) as server:
        client = exchange(url, 4)
        server.check()
        assert server.counters()["rx_frames"] >= client.stats().counters.frames_out - 1
        assert server.counters()["tx_frames_dropped"] == 0


@pytest.mark.udp_multicast
def test_the_exchange_with_the_board_in_another_process_over_udp_multicast():
    """Also issue 31's first reproduction: firmware-sim's status thread read the pty server's statistics
    off the CAN server and died (AttributeError) as the host arrived; now it says when the host comes and
    goes, and the final line counts the link as on a pty."""
    port = random.randint(40_000, 60_000)
    node = random.randint(1, 126)
    spec = f"udp_multicast/239.74.163.{random.randint(1, 254)}?port={port}&node={node}"
    with started(firmware_sim("--units", "2", "--telemetry-rate", "50", "--can", spec)) as board:
        assert board.first_line == f"can://{spec}", board.said
        client = exchange(board.first_line, 2, lossless=False)
        assert client.stats().transport["rx_ignored"] > 0  # udp_multicast loops our own frames back
        time.sleep(1.5)  # the host is silent (closed) for longer than HOST_SILENCE_S: gone
    assert board.proc.returncode == 0
    err = board.said
    assert "Traceback" not in err and "Error" not in err, err
    assert "host connected" in err and "host left" in err, err
    assert " frames in, " in err and "host left 1 time(s)" in err and "0 link error(s)" in err, err


def test_an_error_in_the_serving_thread_is_raised_not_swallowed():
    server = CanServer(Board(BoardConfig(n_units=1), WallClock()), f"virtual/can-err-{os.getpid()}").start()
    time.sleep(0.1)
    server.transport.close()  # the bus goes away under the running loop
    deadline = time.monotonic() + 2.0
    while server._thread_error.error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(LinkError, match="CAN server .* failed"):
        server.check()
    with pytest.raises(LinkError):
        server.close()


def test_firmware_sim_refuses_can_with_pty_options():
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--can", "virtual/x", "--link", "/tmp/never"],
        capture_output=True,
        text=True,
        timeout=10,
    )
    assert done.returncode == 2 and "--can serves a CAN bus" in done.stderr


@pytest.mark.parametrize("url", ["virtual/x", "can://Virtual/vscmg?node=3", "VIRTUAL/0"])
def test_firmware_sim_refuses_a_virtual_bus_no_other_process_can_reach(url):
    """python-can's virtual bus is one process's: ``firmware-sim --can virtual/x`` said it was waiting for
    a host and waited forever, since no ``hil run`` in another process could ever reach it."""
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--can", url],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "virtual bus lives inside one process" in done.stderr and "udp_multicast" in done.stderr
    assert "waiting for a host" not in done.stderr

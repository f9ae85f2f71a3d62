"""One host per board: every host locks its serial port, a second one is refused naming the first.

Without the lock a second host's handshake disarms the board under the first (issue 25, finding 4), and a
host reconnecting through a stale ``--link`` symlink whose pty number another firmware-sim reused talks to
that other board (same default identity, so the handshake's identity check cannot tell). Real ptys from
``firmware-sim`` processes, real pyserial, real ``hil run`` processes; the other host is a
:class:`BoardClient` in the test's own process (an flock is per open file, so it excludes it all the same).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.link.board import BoardClient, ClientConfig, LinkLostEvent, StateEvent, TelemetryEvent
from hil.link.transports.serial_port import SerialTransport
from protocol.errors import PortBusy
from protocol.messages import BoardState
from tests.test_board_client_pty import _connected_to_a_board_then_killed, drive, firmware_sim, setpoint

REPO = Path(__file__).resolve().parents[1]
# Telemetry often enough to watch the host's board; a link watchdog slow enough that a CPU busy beside the
# test (a hil run starting up, other jobs) never trips it: a state change then can only be a disarm.
BOARD = ("--telemetry-rate", "50", "--link-timeout", "2")


def own_cmdline() -> str:
    return " ".join(part for part in Path("/proc/self/cmdline").read_text().split("\0") if part)


def armed_host(link: Path, units: int = 1) -> BoardClient:
    """A host with a session on ``link``'s board of ``units`` units, armed and driving it (reader
    thread)."""
    host = BoardClient(str(link))
    host.connect()
    host.start()
    host.arm()
    drive(host, setpoint(100.0, units), lambda: _armed(host), 3.0)
    host.drain_events()
    return host


def _armed(host: BoardClient) -> bool:
    return host.telemetry is not None and host.telemetry.state is BoardState.ARMED


def assert_undisturbed(host: BoardClient, units: int = 1, frames: int = 10) -> None:
    """``host`` keeps its board: ``frames`` more telemetry frames, every one ARMED, and no state change
    or link loss since its last drain (a second host's handshake would have disarmed it)."""
    events: list = []
    telemetry = lambda: [e for e in events if isinstance(e, TelemetryEvent)]  # noqa: E731
    drive(host, setpoint(100.0, units), lambda: len(telemetry()) >= frames, 5.0, events)
    assert not [e for e in events if isinstance(e, (StateEvent, LinkLostEvent))], events
    states = {e.telemetry.state for e in telemetry()}
    assert states == {BoardState.ARMED} and host.connected


def test_a_second_host_is_refused_naming_the_holder_and_the_first_keeps_its_board(tmp_path: Path):
    link = tmp_path / "board"
    with firmware_sim("--units", "1", *BOARD, "--link", str(link)):
        first = armed_host(link)
        try:
            second = BoardClient(str(link))
            with pytest.raises(PortBusy, match=f"port busy: held by pid {os.getpid()} ") as refused:
                second.connect()
            second.close()
            assert refused.value.holder_pid == os.getpid()  # not firmware-sim, which has the pty open too
            assert refused.value.holder_cmdline is not None
            assert refused.value.holder_cmdline[:100] == own_cmdline()[:100]
            assert str(link) in str(refused.value) and os.path.realpath(link) in str(refused.value)
            assert_undisturbed(first)
        finally:
            first.close()


def test_hil_run_on_a_port_another_host_holds_exits_2_with_one_line_naming_it(
    tmp_path: Path, phone_port: int
):
    link = tmp_path / "board"
    with firmware_sim("--units", "4", *BOARD, "--link", str(link)):
        first = armed_host(link, units=4)
        try:
            phone = f"udp://127.0.0.1:{phone_port}"
            argv = ["run", "--port", str(link), "--phone", phone, "--phone-wait", "1", "--duration", "1"]
            run = subprocess.run(
                [sys.executable, "-m", "hil", *argv, "--no-plots", "--out", str(tmp_path / "runs")],
                cwd=REPO,
                capture_output=True,
                text=True,
                timeout=120,
                env={**os.environ, "PYTHONPATH": str(REPO)},
            )
            errors = [line for line in run.stderr.splitlines() if line.startswith("hil run:")]
            assert run.returncode == 2, run.stderr
            assert "Traceback" not in run.stderr
            assert len(errors) == 1 and f"port busy: held by pid {os.getpid()} (" in errors[0], run.stderr
            assert_undisturbed(first, units=4)
        finally:
            first.close()


def test_a_reconnection_to_a_port_another_host_holds_is_refused_counted_and_logged_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    """Our board was killed with SIGKILL; its symlink now leads to the pty of another firmware-sim (a
    reused pty number) that another host is driving. Same identity, same units: only the lock tells."""
    caplog.set_level(logging.WARNING, logger="hil.link.board.client")
    link, other_link = tmp_path / "board", tmp_path / "other"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.1)
    client = _connected_to_a_board_then_killed(link, config)
    events: list = []
    try:
        with firmware_sim("--units", "1", *BOARD, "--link", str(other_link)):
            other = armed_host(other_link)
            try:
                link.symlink_to(os.readlink(other_link))
                refused = lambda: client.stats().counters.boards_refused >= 3  # noqa: E731
                drive(client, setpoint(100.0, 1), refused, 5.0, events)
                assert not client.connected
                busy = [r.getMessage() for r in caplog.records if "port busy" in r.getMessage()]
                assert len(busy) == 1 and f"held by pid {os.getpid()}" in busy[0], busy
                assert_undisturbed(other)
            finally:
                other.close()
    finally:
        client.close()


def test_the_holder_is_found_when_the_process_that_locked_the_port_is_gone(tmp_path: Path):
    """The lock belongs to the open file, not the process: a child that inherited the descriptor holds it
    after the parent that took it exited, and /proc/locks still names the parent. The holder named is the
    child, found by its descriptor's fdinfo, not firmware-sim (which has the pty open, unlocked)."""
    link = tmp_path / "board"
    script = tmp_path / "holder_marker.py"
    script.write_text(
        "import fcntl, os, sys, time\n"
        "fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)\n"
        "fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
        "if os.fork():\n"
        "    os._exit(0)\n"
        "print(os.getpid(), flush=True)\n"
        "time.sleep(60)\n"
    )
    with firmware_sim("--units", "1", "--link", str(link)):
        locker = subprocess.Popen([sys.executable, str(script), str(link)], stdout=subprocess.PIPE, text=True)
        assert locker.stdout is not None
        child = int(locker.stdout.readline())
        locker.stdout.close()
        locker.wait(timeout=10)
        try:
            with pytest.raises(PortBusy) as refused:
                SerialTransport(str(link)).open()
            assert refused.value.holder_pid == child
            assert (
                refused.value.holder_cmdline is not None
                and "holder_marker.py" in refused.value.holder_cmdline
            )
        finally:
            os.kill(child, 9)
        deadline = time.monotonic() + 10.0
        while True:  # the lock goes with the holder: the port opens again
            try:
                SerialTransport(str(link)).open().close()
                break
            except PortBusy:
                assert time.monotonic() < deadline, "the port stayed locked after its holder was killed"
                time.sleep(0.02)

"""The board client end to end in real time: a real pty, pyserial, and ``firmware-sim`` in its own process
(spawned by the client's spawn:// transport or, where the test must kill and restart it, by the test).
Faults come from firmware-sim's own options (--corrupt, --stall, --hang-at)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bench import child
from bench.child import started
from firmware_sim.servers.transports import EmulatorTransport
from hil.link.board import (
    BoardClient,
    BoardResetEvent,
    ClientConfig,
    CommandEvent,
    ConnectedEvent,
    LinkLostEvent,
    LogEvent,
    StateEvent,
)
from hil.timing.clock import WallClock
from protocol.errors import BoardReset, HandshakeError, LinkError
from protocol.messages import SCHEMA_HASH, ActuatorSetpoint, BoardState, ResetCause, UnitSetpoint

ROTOR = 1  # pulse channel of unit 0's rotor


def setpoint(speed: float, units: int = 4) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(0.0, speed) for _ in range(units)))


def drive(
    client: BoardClient,
    sp: ActuatorSetpoint | None,
    until: Callable[[], bool],
    timeout: float,
    events: list | None = None,
) -> list:
    """A 50 Hz caller's loop: setpoints, ``service()`` (it only collects events while a reader thread
    runs), until ``until()``. Events are appended to ``events`` as they come (``until`` may look at it)."""
    events = [] if events is None else events
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sp is not None:
            client.send_setpoint(sp)
        events += client.service()
        if until():
            return events
        time.sleep(0.02)
    raise AssertionError(f"condition not met within {timeout} s; events: {events[-10:]}")


@contextlib.contextmanager
def firmware_sim(*args: str) -> Iterator[subprocess.Popen[str]]:
    """firmware-sim as its own process (the test kills it; killed on the way out if it did not)."""
    with started(child.firmware_sim(*args), ready="/dev/", stop=signal.SIGKILL) as board:
        yield board.proc


def test_handshake_arm_setpoints_move_the_pulses_and_disarm():
    with BoardClient("spawn://firmware-sim?units=4&telemetry_rate=50") as client:
        info = client.info
        assert info is not None and info.n_units == 4 and info.schema_hash == SCHEMA_HASH
        assert info.reset_cause is ResetCause.POWER_ON and info.identity.model == "ADK-VSCMG"
        client.start()  # real time with a reader thread from here on
        client.arm()
        assert client.state is BoardState.ARMED
        telemetry = []
        for speed in (150.0, 450.0):
            sp = setpoint(speed)
            drive(client, sp, lambda: client.telemetry is not None, 1.0)
            time.sleep(0.1)
            start = client.telemetry_time
            drive(client, sp, lambda s=start: client.telemetry_time != s, 1.0)
            telemetry.append(client.telemetry)
        slow, fast = (t.pulses_us[ROTOR] for t in telemetry)
        assert 1000 < slow < fast <= 2000
        client.disarm()
        assert client.state is BoardState.DISARMED
        drive(client, None, lambda: client.telemetry.pulses_us[ROTOR] == 1000, 1.0)  # from the next frame on
        assert client.telemetry.state is BoardState.DISARMED
        stats = client.stats()
        assert stats.rtt.count >= 2 and 0 < stats.rtt.p50_ms < 50
        assert stats.frames_in > 10 and stats.bad_frames_total == 0 and stats.failed == 0
        assert stats.board_rx_bad == 0


def test_an_incompatible_host_is_refused_with_both_hashes():
    client = BoardClient("spawn://firmware-sim?units=2", config=ClientConfig(schema_hash=SCHEMA_HASH ^ 1))
    try:
        with pytest.raises(HandshakeError, match=f"{SCHEMA_HASH:#010x}.*{SCHEMA_HASH ^ 1:#010x}"):
            client.connect()
        logs = [e.log.text for e in client.drain_events() if isinstance(e, LogEvent)]
        assert any("incompatible host" in text for text in logs)  # the board said so too
    finally:
        client.close()


def test_arming_under_one_percent_byte_corruption_succeeds_by_retries():
    with BoardClient("spawn://firmware-sim?units=2&corrupt=0.01&seed=7") as client:
        client.start()
        cycles = 0
        while client.stats().retries < 3 and cycles < 100:
            client.arm()
            assert client.state is BoardState.ARMED
            client.disarm()
            cycles += 1
        stats = client.stats()
        assert stats.retries >= 3 and stats.failed == 0  # every command got through, some on a retry
        time.sleep(0.5)
        stats = client.stats()
        assert stats.bad_frames_total > 0  # damaged telemetry was dropped, by reason
        assert set(stats.bad_frames) <= {
            "cobs",
            "crc",
            "too_short",
            "too_long",
            "version",
            "unknown_id",
            "length",
            "field_range",
        }


def test_a_link_stall_shows_failsafe_and_the_host_recovers_by_arming():
    with BoardClient("spawn://firmware-sim?units=4&telemetry_rate=50&stall=1.0:0.5") as client:
        client.arm()  # driven by service() in this loop: no reader thread
        sp = setpoint(400.0)
        events = drive(client, sp, lambda: client.state is BoardState.FAILSAFE, 3.0)
        assert any(isinstance(e, StateEvent) and e.new is BoardState.FAILSAFE for e in events)
        client.arm()
        drive(client, sp, lambda: client.telemetry.state is BoardState.ARMED, 1.0)
        drive(client, sp, lambda: client.telemetry.pulses_us[ROTOR] > 1400, 1.0)


def test_an_mcu_hang_is_detected_as_a_watchdog_reset_and_reported():
    with BoardClient("spawn://firmware-sim?units=2&hang_at=1.0&mcu_watchdog=0.3") as client:
        client.start()
        client.arm()

        def setpoint_refused() -> bool:
            try:
                client.send_setpoint(setpoint(300.0, 2))
            except BoardReset:
                return True  # its cause may not be known yet: the board is answering the handshake
            return False

        events = drive(client, None, setpoint_refused, 4.0)
        drive(client, None, lambda: any(isinstance(e, BoardResetEvent) for e in events), 1.0, events)
        with pytest.raises(BoardReset, match="WATCHDOG"):
            client.send_setpoint(setpoint(300.0, 2))
        resets = [e for e in events if isinstance(e, BoardResetEvent)]
        assert len(resets) == 1 and resets[0].cause is ResetCause.WATCHDOG and resets[0].during_session
        assert client.state is BoardState.DISARMED
        client.arm()
        drive(client, setpoint(300.0, 2), lambda: client.telemetry.state is BoardState.ARMED, 1.0)


@pytest.mark.parametrize("rearm", [False, True])
def test_a_vanished_port_is_reconnected_and_the_restarted_board_reported(tmp_path: Path, rearm: bool):
    link = tmp_path / "board"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.2, rearm_on_reconnect=rearm)
    with firmware_sim("--units", "2", "--link", str(link)) as first:
        client = BoardClient(str(link), config=config)
        client.connect()
        client.start()
        client.arm()
        time.sleep(1.0)  # the first board's uptime is well past the second's when it is back
        first.send_signal(signal.SIGKILL)
        link.unlink()  # its dangling symlink could meet a pty number reused by another process
        events = drive(client, None, lambda: not client.connected, 2.0)
    try:
        with firmware_sim("--units", "2", "--link", str(link)):  # a new board on the same symlink
            drive(client, None, lambda: client.connected, 5.0, events)
            drive(client, None, lambda: any(isinstance(e, BoardResetEvent) for e in events), 2.0, events)
            lost = [e for e in events if isinstance(e, LinkLostEvent)]
            connected = [e for e in events if isinstance(e, ConnectedEvent)]
            assert lost and connected and connected[-1].reconnects == 1
            [reset] = [e for e in events if isinstance(e, BoardResetEvent)]
            # the new board's boot id, in its answer to the reconnect's handshake
            assert reset.cause is ResetCause.POWER_ON and "boot id changed" in reset.evidence, reset
            if rearm:
                drive(client, None, lambda: any(isinstance(e, CommandEvent) for e in events), 1.0, events)
                assert [e.ok for e in events if isinstance(e, CommandEvent)] == [True]
                assert client.state is BoardState.ARMED
                client.send_setpoint(setpoint(300.0, 2))  # armed again, as the caller asked
            else:
                assert client.state is BoardState.DISARMED  # never re-armed silently
                with pytest.raises(BoardReset, match="POWER_ON"):
                    client.send_setpoint(setpoint(300.0, 2))
                client.arm()
            assert client.stats().counters.reconnects == 1
    finally:
        client.close()


@pytest.mark.parametrize("away_s", [1.7, 3.3])
def test_a_port_that_comes_back_is_tried_at_once_not_at_the_back_offs_next_step(
    tmp_path: Path, away_s: float
):
    """The default back-off (50 ms doubling to 2 s) tries a lost port at 0.05, 0.15, 0.35, 0.75, 1.55,
    3.15, 5.15 s …: a board back ``away_s`` after the loss (just past a step) waited 1.5 or 1.9 s more,
    and a run killed late lost its board for it (a pty campaign with FAULT_SEED=2222: back 0.8 s before
    the run's end, the run ended before the host tried again). The client watches the port's path while
    the link is down: there again, it is opened at once (timed to the open, not to the new board's answer,
    which a loaded machine may delay), and the session is back."""
    link = tmp_path / "board"
    client = BoardClient(str(link), config=ClientConfig())
    with firmware_sim("--units", "2", "--link", str(link)) as first:
        client.connect()
        client.start()
        first.send_signal(signal.SIGKILL)
        events = drive(client, None, lambda: not client.connected, 2.0)
        lost_at = time.monotonic()
    try:
        time.sleep(max(away_s - (time.monotonic() - lost_at), 0.0))
        with firmware_sim("--units", "2", "--link", str(link)):
            back = time.monotonic()
            drive(client, None, lambda: client.transport.is_open, 5.0, events)
            took = time.monotonic() - back
            assert took < 0.5, f"opened {took:.2f} s after the port came back, {away_s} s after the loss"
            drive(client, None, lambda: client.connected, 10.0, events)
            assert any(isinstance(e, BoardResetEvent) for e in events + client.service())
    finally:
        client.close()


def test_a_board_restarted_long_before_the_host_is_back_is_reported_reset(tmp_path: Path):
    """The soak's find (a CI run under load): a board killed early in its session and restarted, which then
    ran longer than the old one had before the host reached it again, so its uptime did not go back. Its
    uptime is still short of the old board's running on through the outage: reported as a reset."""
    link, other = tmp_path / "board", tmp_path / "board-2"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.2)
    with firmware_sim("--units", "2", "--link", str(link)) as first:
        client = BoardClient(str(link), config=config)
        client.connect()
        client.start()
        client.arm()
        taken = lambda: client.telemetry is not None and client.telemetry.rx_frames >= 20  # noqa: E731
        drive(client, setpoint(300.0, 2), taken, 3.0)  # a session under way, well under 2.5 s old
        first.send_signal(signal.SIGKILL)
        link.unlink()
        events = drive(client, None, lambda: not client.connected, 2.0)
    try:
        with firmware_sim("--units", "2", "--link", str(other)):
            time.sleep(2.5)  # the new board runs on while the host cannot reach it yet
            link.symlink_to(other.readlink())  # then its port appears where the host looks
            drive(client, None, lambda: client.connected, 5.0, events)
            drive(client, None, lambda: any(isinstance(e, BoardResetEvent) for e in events), 2.0, events)
            [reset] = [e for e in events if isinstance(e, BoardResetEvent)]
            assert reset.cause is ResetCause.POWER_ON and reset.during_session, reset
            # the answer to the reconnect's handshake tells it: another boot id (a board that says none is
            # told by the first sample after: a heartbeat's uptime shorter than the old board had run, its
            # age, or the telemetry's count of frames taken going back; tests/test_board_link_beside_clocks)
            assert "boot id changed" in reset.evidence, reset.evidence
            assert client.state is BoardState.DISARMED  # never re-armed silently
            with pytest.raises(BoardReset, match="POWER_ON"):
                client.send_setpoint(setpoint(300.0, 2))
    finally:
        client.close()


def _connected_to_a_board_then_killed(link: Path, config: ClientConfig) -> BoardClient:
    """A client that had a session with a 1-unit firmware-sim on ``link``, killed with SIGKILL since (its
    symlink removed, as a new firmware-sim would replace it)."""
    with firmware_sim("--units", "1", "--link", str(link)) as first:
        client = BoardClient(str(link), config=config)
        client.connect()
        first.send_signal(signal.SIGKILL)
        link.unlink()
    return client


def test_another_board_on_the_reconnected_port_is_refused_and_ours_taken_back(tmp_path: Path):
    """After a kill the port's name can reach another board (a pty name reused by another process, a board
    swapped): it is never commanded, the refusal is reported, and the client goes on looking for its own
    board, which it takes back when it answers again."""
    link = tmp_path / "board"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.1)
    client = _connected_to_a_board_then_killed(link, config)
    events: list = []
    try:
        with firmware_sim("--units", "2", "--link", str(link)) as foreign:
            refused = lambda: client.stats().counters.boards_refused >= 1  # noqa: E731
            drive(client, setpoint(100.0, 1), refused, 5.0, events)
            assert not client.connected
            foreign.send_signal(signal.SIGKILL)
            link.unlink()
        refusals = [e for e in events if isinstance(e, LinkLostEvent) and "another board" in e.reason]
        assert refusals and "2 units" in refusals[0].reason and "1 units" in refusals[0].reason
        with firmware_sim("--units", "1", "--link", str(link)):
            drive(client, None, lambda: client.connected, 5.0, events)
        assert client.info is not None and client.info.n_units == 1
        assert client.stats().counters.reconnects == 1
    finally:
        client.close()


def test_a_port_that_only_reaches_another_board_ends_in_a_link_error_that_says_so(tmp_path: Path):
    link = tmp_path / "board"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.1, reconnect_give_up_s=1.0)
    client = _connected_to_a_board_then_killed(link, config)
    try:
        with firmware_sim("--units", "2", "--link", str(link)):
            with pytest.raises(LinkError, match="gave up reconnecting.*another board answered.*2 units"):
                drive(client, None, lambda: False, 5.0)
    finally:
        client.close()


def test_the_reader_threads_errors_reach_the_callers_loop(tmp_path: Path):
    link = tmp_path / "board"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.1, reconnect_give_up_s=0.5)
    with firmware_sim("--units", "1", "--link", str(link)) as board:
        client = BoardClient(str(link), config=config)
        client.connect()
        client.start()
        board.send_signal(signal.SIGKILL)  # and it never comes back
        link.unlink()
        with pytest.raises(LinkError, match="gave up reconnecting after"):
            drive(client, setpoint(100.0, 1), lambda: False, 3.0)
        with pytest.raises(LinkError, match="gave up"):  # every later call too
            client.send_setpoint(setpoint(100.0, 1))
        client.close()

    def broken_callback(event: object) -> None:
        raise ZeroDivisionError("a bug in the caller's event handler")

    client = BoardClient(EmulatorTransport("emu://?units=1", WallClock()), on_event=broken_callback)
    with pytest.raises(ZeroDivisionError):
        client.connect()  # no thread yet: the caller's own call raises it
    client = BoardClient(EmulatorTransport("emu://?units=1", WallClock()))
    client.connect()
    client.on_event = broken_callback
    client.start()
    with pytest.raises(LinkError, match="reader thread failed: ZeroDivisionError") as err:
        drive(client, None, lambda: False, 2.0)
    assert isinstance(err.value.__cause__, ZeroDivisionError)
    client.close()

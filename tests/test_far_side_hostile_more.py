"""A far side that sends well-formed frames (valid COBS, CRC, fields in range) that are hostile: telemetry
repeated verbatim, uptimes and frame counts leaping far ahead, telemetry for another number of units or
channels than the board announced, a flood of board logs. Through a real pseudo-terminal and a real
python-can virtual bus to the real board client, with a scripted board on the far end (the board
emulator never sends such frames), and through the sans-IO session for the properties.

Before the fixes: a Telemetry frame repeated verbatim for 2 s kept 2 s old telemetry live (its receive
time moved on each copy); one Telemetry with an uptime of 2e9 ms five seconds into a session became the
reference, so the next honest one "went back" — a spurious board reset, a handshake that disarms the
board, its telemetry held meanwhile as live; a Telemetry for 0 units from a 4-unit board was held as the
latest (the calibration tools index it by unit: IndexError); 20 000 board Log frames made 20 000 host
log records.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.link.board import BoardClient, BoardResetEvent, LogEvent, Phase, Session, TelemetryEvent
from hil.link.board.leaps import REANCHOR_AFTER_S
from hil.link.board.session import BOARD_LOGS_PER_S
from hil.link.transports.can_bus import CanTransport
from protocol.can import Direction
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    BoardState,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    ResetCause,
    Severity,
    Telemetry,
    UnitState,
)
from tests.can_support import virtual_url

UNITS = 4


def telemetry(
    time_ms: int, units: int = UNITS, rx_frames: int = 10, channels: int | None = None
) -> Telemetry:
    channels = 2 * units if channels is None else channels
    return Telemetry(
        time_ms=time_ms,
        state=BoardState.DISARMED,
        units=tuple(UnitState() for _ in range(units)),
        pulses_us=(1000,) * channels,
        rx_frames=rx_frames,
    )


def hello_reply() -> HelloReply:
    return HelloReply(
        schema_hash=SCHEMA_HASH, state=BoardState.DISARMED, n_units=UNITS, frame_rate_hz=50, model="SCRIPTED"
    )


class ScriptedBoard:
    """The far side: answers every Hello with a HelloReply and every reliable command with an Ack (a
    thread), and sends whatever the test gives it, through ``read(timeout)`` / ``write(bytes)``."""

    def __init__(self, read: Callable[[float], bytes], write: Callable[[bytes], None]) -> None:
        self._read, self._write = read, write
        self.framer = Framer()
        self.hellos = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="scripted-board", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        deframer = Deframer()
        while not self._stop.is_set():
            for event in deframer.feed(self._read(0.02)):
                if not isinstance(event, Frame):
                    continue
                if isinstance(event.message, Hello):
                    self.hellos += 1
                    self.send(hello_reply())
                elif event.message.RELIABLE:
                    self.send(Ack(msg_id=event.msg_id, seq=event.seq))

    def send(self, message: object) -> bytes:
        """Send ``message`` with the board's next sequence number; returns its wire bytes."""
        with self._lock:
            _, wire = self.framer.encode(message)
            self._write(wire)
            return wire

    def raw(self, data: bytes) -> None:
        with self._lock:
            self._write(data)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


@contextmanager
def pty_board() -> Iterator[tuple[ScriptedBoard, BoardClient]]:
    """A scripted board on a real pseudo-terminal, and a connected board client (reader thread running)."""
    master, slave = os.openpty()
    tty.setraw(slave)

    def read(timeout: float) -> bytes:
        ready, _, _ = select.select([master], [], [], timeout)
        return os.read(master, 65536) if ready else b""

    def write(data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(master, view) :]

    try:
        with connected(ScriptedBoard(read, write), BoardClient(os.ttyname(slave))) as pair:
            yield pair
    finally:
        os.close(master)
        os.close(slave)


@contextmanager
def can_board() -> Iterator[tuple[ScriptedBoard, BoardClient]]:
    """The same on a python-can ``virtual`` bus: the board's end is a can:// transport sending to the host."""
    url = virtual_url()
    with CanTransport(url, sends=Direction.TO_HOST) as far:
        with connected(ScriptedBoard(far.read, far.write), BoardClient(url)) as pair:
            yield pair


@contextmanager
def connected(board: ScriptedBoard, client: BoardClient) -> Iterator[tuple[ScriptedBoard, BoardClient]]:
    """The client's session with the scripted board: connected and started, then both stopped."""
    try:
        client.connect(timeout=5.0)
        client.start()
        yield board, client
    finally:
        client.close()
        board.stop()


def settle(client: BoardClient, until: Callable[[], bool], timeout: float = 3.0) -> None:
    end = time.monotonic() + timeout
    while not until():
        assert time.monotonic() < end, "the client did not get there in time"
        time.sleep(0.01)


# ============================================================================ through real links
@pytest.mark.parametrize("link", [pty_board, can_board], ids=["pty", "can-virtual"])
def test_telemetry_repeated_verbatim_does_not_keep_old_telemetry_live(link):
    with link() as (board, client):
        wire = board.send(telemetry(100))
        settle(client, lambda: client.telemetry is not None)
        first = client.telemetry_time
        for _ in range(10):
            time.sleep(0.05)
            board.raw(wire)  # the same frame again: same sequence number, same content
        settle(client, lambda: client.stats().frames_in >= 12)
        stats = client.stats()
        assert client.telemetry_time == first  # the telemetry is as old as it is, not refreshed
        assert stats.counters.telemetry_repeats == 10 and stats.duplicates == 10
        board.send(telemetry(150))  # the board's next telemetry is taken as ever
        settle(client, lambda: client.telemetry.time_ms == 150)


@pytest.mark.parametrize("link", [pty_board, can_board], ids=["pty", "can-virtual"])
def test_one_far_future_uptime_is_dropped_and_counted_not_a_board_reset(link):
    with link() as (board, client):
        board.send(telemetry(100))
        settle(client, lambda: client.telemetry is not None)
        board.send(telemetry(2_000_000_000))  # 23 days of uptime, 0.05 s after 100 ms
        board.send(Heartbeat(time_ms=1_500_000_000, state=int(BoardState.BOOT)))
        board.send(telemetry(150, rx_frames=3_000_000_000))  # a frame count no host has sent
        board.send(telemetry(200))
        settle(client, lambda: client.telemetry.time_ms == 200)
        time.sleep(0.2)  # a re-handshake, were there one, would have been sent by now
        stats = client.stats()
        assert board.hellos == 1 and stats.counters.resets == 0 and client.connected
        assert stats.counters.board_leaps == 3 and client.state is BoardState.DISARMED
        events = client.drain_events()
        assert not [e for e in events if isinstance(e, BoardResetEvent)]
        assert [e.telemetry.time_ms for e in events if isinstance(e, TelemetryEvent)] == [100, 200]


def test_telemetry_for_units_or_channels_the_board_has_not_is_dropped_and_counted():
    with pty_board() as (board, client):
        board.send(telemetry(100))
        settle(client, lambda: client.telemetry is not None)
        for misfit in (telemetry(120, units=0), telemetry(140, units=7), telemetry(160, channels=3)):
            board.send(misfit)
        board.send(telemetry(180))
        settle(client, lambda: client.telemetry.time_ms == 180)
        taken = [e.telemetry.time_ms for e in client.drain_events() if isinstance(e, TelemetryEvent)]
        assert taken == [100, 180] and client.stats().counters.telemetry_misfits == 3


def test_a_flood_of_board_logs_is_reported_but_logged_at_a_bounded_rate(caplog):
    with pty_board() as (board, client), caplog.at_level(logging.WARNING):
        log = Log(severity=Severity.ERROR, code=7, text="x" * 200)
        board.raw(b"".join(board.framer.encode(log)[1] for _ in range(5000)))
        settle(client, lambda: client.stats().frames_in >= 5001, timeout=10.0)
        records = [r for r in caplog.records if r.getMessage().startswith("board: ")]
        assert len(records) <= 2 * BOARD_LOGS_PER_S
        logs = [e for e in client.drain_events() if isinstance(e, LogEvent)]
        assert len(logs) == 5000  # every one reported
        assert client.stats().counters.board_logs_unlogged == 5000 - len(records)


# ============================================================================ sans-IO properties
def session() -> tuple[Session, Framer]:
    """A session after a handshake with a 4-unit board (its framer: the board's side)."""
    s = Session()
    s.link_up(0.0)
    board = Framer()
    s.feed(board.encode(hello_reply())[1], 0.01)
    assert s.phase is Phase.READY
    s.take_events()
    return s, board


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    leap_ms=st.integers(30_000, 2**32 - 30_000),  # ahead of the honest uptime, short of wrapping past it
    at=st.floats(0.05, 20.0),
    heartbeat=st.booleans(),
)
def test_any_leap_ahead_is_dropped_and_the_honest_board_goes_on_unreset(leap_ms, at, heartbeat):
    s, board = session()
    t0 = 0.02
    s.feed(board.encode(telemetry(1_000))[1], t0)
    honest = 1_000 + round((at - t0) * 1000)
    hostile = honest + leap_ms
    absurd = Heartbeat(time_ms=hostile, state=int(BoardState.BOOT)) if heartbeat else telemetry(hostile)
    s.feed(board.encode(absurd)[1], at)
    assert s.counters.board_leaps == 1 and s.state is BoardState.DISARMED  # the BOOT it said: not taken
    s.feed(board.encode(telemetry(honest + 20))[1], at + 0.02)
    assert s.counters.resets == 0 and s.phase is Phase.READY
    assert s.telemetry is not None and s.telemetry.time_ms == honest + 20


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    lag=st.floats(0.0, 0.2),  # the share of wall time the board's clock loses (an emulator not run enough)
    run_s=st.floats(1.0, 3600.0),
    outage_s=st.floats(0.05, 2.0),
    samples=st.integers(1, 12),
)
def test_a_board_whose_clock_falls_behind_is_not_taken_for_a_restart_at_a_reconnect(
    lag, run_s, outage_s, samples
):
    """simavr's harness lets the board's clock fall behind the wall when it is not run (a loaded machine),
    by as much as the load takes. The same board found again after a lost link — its uptime short of the
    host time since its first answer by all that lag — was reported reset when the check ran from the boot;
    it runs from when the board was last heard of, where the lag over an outage stays within the slack."""
    s, board = session()
    for k in range(1, samples + 1):
        t = 0.01 + run_s * k / samples
        s.feed(board.encode(telemetry(round(t * (1 - lag) * 1000), rx_frames=10 + k))[1], t)
    lost_at = 0.01 + run_s
    s.link_down(lost_at, "port vanished")
    back = lost_at + outage_s
    s.link_up(back)
    s.feed(board.encode(hello_reply())[1], back + 0.01)
    uptime_ms = round((back + 0.02) * (1 - lag) * 1000)
    s.feed(board.encode(telemetry(uptime_ms, rx_frames=11 + samples))[1], back + 0.02)
    assert s.counters.resets == 0 and s.counters.reconnects == 1
    assert s.telemetry is not None and s.telemetry.time_ms == uptime_ms


@pytest.mark.parametrize("before_answer", [False, True])
def test_a_board_restarted_before_it_sent_a_sample_is_a_reset_even_if_it_speaks_before_answering(
    before_answer,
):
    """A board killed right after the handshake (no sample yet) and started again ~0.6 s later: its uptime at
    the reconnect is short of the time since its first answer. A sample the new board sends before it
    answers the reconnect's Hello (its telemetry, on a host's first bytes) had been taken as the board's
    latest word, against which the first sample after the answer then looked in time: no reset."""
    s, board = session()
    s.link_down(0.05, "port vanished")
    s.link_up(1.6)
    if before_answer:
        s.feed(board.encode(telemetry(590))[1], 1.64)
    s.feed(board.encode(hello_reply())[1], 1.65)
    s.feed(board.encode(telemetry(600))[1], 1.67)
    assert s.counters.resets == 1 and s.counters.reconnects == 1


def test_a_backlog_read_all_at_once_after_a_pause_is_taken_whole():
    s, board = session()
    s.feed(board.encode(telemetry(1_000))[1], 0.02)
    backlog = b"".join(board.encode(telemetry(1_000 + 50 * k, rx_frames=10))[1] for k in range(1, 401))
    s.feed(backlog, 20.1)  # 20 s of telemetry, read in one go by a host paused that long
    assert s.counters.board_leaps == 0 and s.telemetry.time_ms == 21_000


def test_a_real_reset_is_still_one():
    s, board = session()
    s.feed(board.encode(telemetry(30_000, rx_frames=5_000))[1], 0.02)
    out = s.feed(board.encode(telemetry(40, rx_frames=1))[1], 0.1)
    assert s.phase is Phase.HANDSHAKING and out  # a Hello asks the board why
    assert s.counters.board_leaps == 0


def test_an_absurd_first_uptime_is_outgrown_not_a_board_blind_for_ever():
    s, board = session()
    s.feed(board.encode(telemetry(3_000_000_000))[1], 0.02)  # the anchor is the absurd one
    t, uptime, taken = 0.02, 100, []
    while t < 0.1 + 2 * REANCHOR_AFTER_S:
        t, uptime = t + 0.05, uptime + 50
        s.feed(board.encode(telemetry(uptime))[1], t)
        taken += [e.telemetry.time_ms for e in s.take_events() if isinstance(e, TelemetryEvent)]
    assert s.counters.board_reanchors == 1 and s.phase is Phase.READY
    assert taken and taken[-1] == uptime and s.counters.board_leaps <= REANCHOR_AFTER_S / 0.05 + 1


def test_a_reset_cause_is_not_made_up_by_a_leap_then_a_real_reset_still_reports():
    s, board = session()
    s.feed(board.encode(telemetry(1_000))[1], 0.02)
    s.feed(board.encode(telemetry(900_000_000))[1], 0.04)  # dropped
    s.feed(board.encode(telemetry(20, rx_frames=1))[1], 0.06)  # the board really reset
    assert s.phase is Phase.HANDSHAKING
    reply = HelloReply(
        schema_hash=SCHEMA_HASH,
        state=BoardState.DISARMED,
        n_units=UNITS,
        frame_rate_hz=50,
        model="SCRIPTED",
        reset_cause=ResetCause.WATCHDOG,
    )
    s.feed(board.encode(reply)[1], 0.08)
    resets = [e for e in s.take_events() if isinstance(e, BoardResetEvent)]
    assert [e.cause for e in resets] == [ResetCause.WATCHDOG]
    assert "went back from 1000 ms" in resets[0].evidence


def test_a_flood_of_board_logs_is_recorded_in_the_run_at_a_bounded_rate(tmp_path):
    """20 000 board Log frames in a burst wrote 20 000 flushed lines to ``events.jsonl`` (megabytes a
    second for as long as the board floods). At most ``BOARD_LOGS_RECORDED_PER_S`` a second of host time
    are recorded; the rest are counted, and the next one recorded says how many went before it."""
    from hil.link.board import BoardClient
    from hil.runtime.faults import FaultJournal
    from hil.runtime.runlog import EventLog, read_events
    from hil.runtime.watch import BOARD_LOGS_RECORDED_PER_S, BoardWatch
    from hil.timing.clock import LockstepClock

    with BoardClient("emu://?units=4", clock=LockstepClock()) as client:
        events = EventLog(tmp_path / "events.jsonl")
        watch = BoardWatch(client, events, FaultJournal(), 0.25)
        flood = [LogEvent(5.0 + k * 1e-5, Log(Severity.WARNING, 7, f"flood {k}")) for k in range(20_000)]
        watch.on_events(flood)
        watch.on_events([LogEvent(6.5, Log(Severity.INFO, 1, "after"))])
        events.close()
    records = [r for r in read_events(tmp_path / "events.jsonl")[0] if r["kind"] == "board_log"]
    assert len(records) == BOARD_LOGS_RECORDED_PER_S + 1
    assert [r["text"] for r in records[:3]] == ["flood 0", "flood 1", "flood 2"]
    unrecorded = 20_000 - BOARD_LOGS_RECORDED_PER_S
    assert records[-1]["text"] == "after" and records[-1]["not_recorded_before"] == unrecorded
    assert watch.board_logs_unrecorded == unrecorded

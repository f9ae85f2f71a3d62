"""The host itself stops reading for a while — its process paused or swapped out, its reader thread held —
and then finds the board's backlog waiting: telemetry from the start of its pause (a pty keeps the oldest
bytes; the board drops what does not fit). Before the fix every frame of it was stamped with the time it
was read, so a board the host had not seen for seconds was shown live, and a run's record had no stale
episode for the pause. Now a read that comes late dates what it carries by the board's clock
(:mod:`hil.link.board.made_at`), and a prompt read by its receive time — so a board whose clock lags (an
emulator catching up) is never taken for stale.

Through the sans-IO session with injected time (Hypothesis: clock rates, pauses, how much of the backlog
the buffer kept, latencies), and through a real pty against ``firmware-sim`` with the client's reader
thread held.
"""

from __future__ import annotations

import math
import random
import threading
import time
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sim_support import Sim, sims
from test_board_link_beside_echo import connected, telemetry

from hil.link.board import BoardClient, ClientConfig, Session, TelemetryEvent
from hil.link.board.made_at import CATCH_UP_S, PROMPT_READ_S, WINDOW_S
from protocol.frame import Framer

PERIOD_S = 0.02  # the board's telemetry period here (50 Hz)
JITTER_S = 0.005  # the link's latency varies by up to this


class Board:
    """A board sending telemetry every PERIOD_S of host time, its clock at ``rate`` of the host's."""

    def __init__(self, rate: float, first_ms: float) -> None:
        self.rate, self.first_ms = rate, first_ms
        self.framer = Framer()

    def uptime_ms(self, t: float) -> int:
        return round(self.first_ms + self.rate * t * 1000.0)

    def frame(self, t: float) -> bytes:
        """The telemetry the board makes at host time ``t``."""
        return self.framer.encode(telemetry(self.uptime_ms(t)))[1]


def read_promptly(s: Session, board: Board, start: float, end: float, rng: random.Random) -> float:
    """The host reads every frame the board makes from ``start`` to ``end`` soon after it was made; each is
    dated by its receive time. Returns the end of the last read."""
    read_end = start
    t = start
    while t + PERIOD_S < end:
        t += PERIOD_S
        now = t + rng.uniform(0.0, JITTER_S)
        s.poll(now)
        s.feed(board.frame(t), now, read_end)
        assert s.telemetry_time == now
        read_end = now
    return read_end


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    rate=st.floats(0.85, 1.15),
    pause_at=st.floats(3.0, 20.0),
    pause_s=st.floats(0.3, 12.0),
    kept=st.integers(1, 80),
    seed=st.integers(0, 2**16),
)
@example(rate=1.0, pause_at=5.0, pause_s=3.0, kept=10, seed=0)  # the backlog 2.8 s old: was shown live
@example(rate=1.0, pause_at=12.0, pause_s=6.0, kept=1, seed=0)  # the board's fresh frames refused as leaps
def test_a_backlog_read_after_a_host_pause_is_dated_by_the_board_clock(rate, pause_at, pause_s, kept, seed):
    """The host pauses ``pause_s`` at ``pause_at``; the buffer kept the first ``kept`` frames of the pause.
    Read in one go at the end of the pause, the held telemetry is dated near when the board made it —
    within the drift its clock can gather over the pause and the window — never later than its read,
    never before the host's last read; the next prompt reads are dated by their receive time again, and
    none of the board's frames is refused (the leap check's anchor once slid onto an old backlog frame at
    its read time, and the fresh frames after a pause over 5 s were then "leaps")."""
    rng = random.Random(seed)
    s, _ = connected()
    board = Board(rate, 7_000.0)
    read_end = read_promptly(s, board, 0.01, pause_at, rng)
    resume = pause_at + pause_s
    made = [read_end + (i + 1) * PERIOD_S for i in range(int((resume - read_end) / PERIOD_S))][:kept]
    s.poll(resume)
    s.feed(b"".join(board.frame(t) for t in made), resume, read_end)
    assert s.counters.board_leaps == 0 and s.telemetry is not None
    newest = made[-1]
    assert s.telemetry.time_ms == board.uptime_ms(newest)
    tel_t = s.telemetry_time
    assert tel_t is not None and read_end <= tel_t <= resume
    drift = abs(1.0 - rate) * (resume - read_end + WINDOW_S)
    assert abs(tel_t - newest) <= drift + JITTER_S + 0.002, (tel_t, newest)
    if resume - newest > 0.25 + drift + JITTER_S:  # the host's stale bound: it was blind, and says so
        assert resume - tel_t > 0.25
    paused_from = read_end
    t, read_end = resume, resume  # the board's next frames, fresh, read promptly: dated within the drift
    while t < resume + CATCH_UP_S + 2 * PERIOD_S:  # at most until the reads were prompt for CATCH_UP_S
        t += PERIOD_S
        now = t + 0.002
        s.poll(now)
        s.feed(board.frame(t), now, read_end)
        read_end = now
        drift = abs(1.0 - rate) * (now - paused_from + WINDOW_S)
        assert s.telemetry_time is not None and now - drift - JITTER_S - 0.002 <= s.telemetry_time <= now
    read_promptly(s, board, t, t + 1.0, rng)  # then by their receive time
    assert (s.counters.board_leaps, s.counters.board_reanchors, s.counters.resets) == (0, 0, 0)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    rate=st.floats(0.85, 1.15), lag_s=st.floats(0.05, 2.0), at=st.floats(3.0, 15.0), seed=st.integers(0, 999)
)
def test_a_board_clock_that_lags_while_the_host_reads_promptly_never_makes_fresh_frames_old(
    rate, lag_s, at, seed
):
    """An emulated board falls ``lag_s`` behind the host (its process not run) and catches up by sending
    what it owes at once, while the host keeps reading (its reads come back empty meanwhile): every frame
    is dated by its receive time — a lagging board's fresh telemetry is never taken for stale."""
    rng = random.Random(seed)
    s, _ = connected()
    board = Board(rate, 1_000.0)
    read_end = read_promptly(s, board, 0.01, at, rng)
    while read_end < at + lag_s:  # empty reads: the host is there, the board silent
        read_end += 0.01
    owed = [at + (i + 1) * PERIOD_S for i in range(round(lag_s / PERIOD_S))]
    s.feed(b"".join(board.frame(t) for t in owed), read_end + 0.001, read_end)
    assert s.telemetry_time == read_end + 0.001


def test_a_read_that_waited_long_on_a_silent_board_is_dated_fresh_by_its_clock():
    """A late read (the board said nothing for a while, the host was there) holding a frame just made: dated
    within the link's latency of its receive time, not at the read before (the window's least offset)."""
    s, _ = connected()
    board = Board(1.0, 5_000.0)
    read_end = read_promptly(s, board, 0.01, 4.0, random.Random(1))
    t = read_end + 0.8
    s.poll(t)
    s.feed(board.frame(t), t + 0.003, read_end)
    assert s.telemetry_time is not None and t + 0.003 - s.telemetry_time <= JITTER_S + 0.002
    assert PROMPT_READ_S < 0.8


# ====================================================================== a real pty, the reader thread held
def test_a_held_reader_thread_takes_the_pty_backlog_for_what_it_is(tmp_path: Path):
    """``firmware-sim`` at 1 kHz telemetry on a pty; the client's reader thread is held for 2 s and let go.
    The pty then holds telemetry from the start of the hold (the board drops what does not fit): while the
    client reads it, the held telemetry's time is never later than when the board made it (its uptime on
    the host's clock, by the least offset seen before), so the backlog reads as 1.5 s or more old — and a
    moment later the fresh telemetry is live."""
    link = tmp_path / "board"
    with sims(tmp_path) as boards:
        boards.append(Sim(tmp_path, link, "--units", "2", "--telemetry-rate", "1000"))
        seen: list[tuple[float, int, float | None]] = []
        lock = threading.Lock()
        client: BoardClient | None = None

        def on_event(event: Any) -> None:
            if isinstance(event, TelemetryEvent) and client is not None:
                held = client.telemetry
                assert held is not None
                with lock:
                    seen.append((event.t, held.time_ms, client.telemetry_time))

        client = BoardClient(str(link), config=ClientConfig(), on_event=on_event)
        try:
            client.connect()
            client.start()
            time.sleep(1.0)
            with lock:
                offset = min(t - ms / 1000.0 for t, ms, _ in seen)  # the link's least latency, as read
                before = len(seen)
            client.stop()
            held_at = client.clock.now()
            time.sleep(2.0)
            resumed = client.clock.now()
            client.start()
            time.sleep(0.5)
            with lock:
                after = seen[before:]
            assert after
            made = [(offset + ms / 1000.0, tel_t) for _, ms, tel_t in after]
            backlog = [m for m, _ in made if m < held_at + 0.5]
            assert backlog, "the pty kept no telemetry from the hold: nothing to judge"
            for board_made, tel_t in made:
                assert tel_t is not None and tel_t <= board_made + 0.05, (
                    board_made - resumed,
                    tel_t - resumed,
                )
            live_by = time.monotonic() + 5.0  # live again soon (a loaded machine's firmware-sim may lag)
            while client.clock.now() - (client.telemetry_time or -math.inf) >= 0.1:
                assert time.monotonic() < live_by, "the fresh telemetry never read as live"
                time.sleep(0.02)
        finally:
            client.close()

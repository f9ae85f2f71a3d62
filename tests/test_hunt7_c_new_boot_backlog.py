"""The host's view of a board's telemetry is never fresher than the board made it, and its age never below 0.

* A board that reset while the host itself was not reading (its process paused, its reader thread held)
  leaves a backlog of its *new* boot. That boot's clock has no offset on the host's yet, and its first
  sample was dated by its receive time — and, so dated, it ended the session's "behind" state: the rest
  of the backlog, seconds old, was dated as just read (shown live). Through the sans-IO session fed the
  board's framed bytes with injected time (Hypothesis: pauses, reset moments, how much the pty kept).
* In real time the client's reader thread stamps a frame after the control tick took its time ``t``:
  the view's telemetry age ``t - made`` came out negative, the row's ``tel_age_ms`` with it. Against
  ``firmware-sim`` behind a real pty, the client's reader thread running.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from sim_support import Sim, sims
from test_board_link_beside_echo import connected
from test_board_link_beside_host_pause import JITTER_S, PERIOD_S, Board, read_promptly

from hil.link.board import BoardClient, ClientConfig
from hil.link.board.made_at import WINDOW_S
from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog
from hil.runtime.watch import BoardWatch


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.generate],
)
@given(
    rate=st.floats(0.99, 1.01),  # a board's clock against the host's: 1 % either way
    pause_s=st.floats(0.4, 6.0),
    reset_in=st.floats(0.0, 1.0),
    kept=st.integers(1, 60),
    first_ms=st.integers(0, 300),
    seed=st.integers(0, 999),
)
def test_a_new_boots_backlog_read_after_a_host_pause_is_never_dated_live(
    rate, pause_s, reset_in, kept, first_ms, seed
):
    """The host pauses ``pause_s``; the board resets ``reset_in`` of the way into the pause and its new boot
    sends telemetry from ``first_ms`` of uptime; the pty kept the first ``kept`` frames of the pause (the
    old boot's, then the new boot's). Read in one go at the resume, the telemetry held is never dated
    later than the board made it, nor before the host's last read: a stale value is not shown as live."""
    rng = random.Random(seed)
    s, _ = connected()
    old = Board(rate, 9_000.0)
    read_end = read_promptly(s, old, 0.01, 6.0, rng)
    resume = read_end + pause_s
    reset_at = read_end + reset_in * pause_s
    new = Board(rate, -rate * reset_at * 1000.0)  # booted at reset_at: its first telemetry first_ms later
    made = [read_end + (i + 1) * PERIOD_S for i in range(int(pause_s / PERIOD_S))]
    frames = [
        (t, (old if t < reset_at else new).frame(t))
        for t in made
        if not reset_at <= t < reset_at + first_ms / 1e3
    ][:kept]
    newest = frames[-1][0]
    s.poll(resume)
    s.feed(b"".join(f for _, f in frames), resume, read_end)
    tel_t = s.telemetry_time
    drift = abs(1.0 - rate) * (resume - read_end + WINDOW_S)
    assert tel_t is not None and read_end <= tel_t <= newest + drift + JITTER_S + 0.002, (
        f"the newest telemetry, made {resume - newest:.3f} s before its read, was dated "
        f"{resume - tel_t:.3f} s before it"
    )


def test_a_views_telemetry_age_is_never_negative_in_real_time(tmp_path: Path):
    """The control tick takes its time, then looks at the board a moment later (its other work first)
    while the reader thread takes 1 kHz telemetry: the age is never below 0 and the telemetry never made
    after the tick's time."""
    link = tmp_path / "board"
    with sims(tmp_path) as boards:
        boards.append(Sim(tmp_path, link, "--units", "2", "--telemetry-rate", "1000"))
        client = BoardClient(str(link), config=ClientConfig())
        try:
            client.connect()
            client.start()
            watch = BoardWatch(client, EventLog(None), FaultJournal(), 0.25)
            time.sleep(0.3)
            watch.view(client.clock.now())  # the telemetry held by now seen once
            ages = []
            for _ in range(100):
                t = client.clock.now()
                time.sleep(0.004)  # the tick's other work: the reader thread takes a frame meanwhile
                view = watch.view(t)
                assert view.age_s is not None and view.age_s >= 0.0, view.age_s
                assert view.made_s is None or view.made_s <= t, (view.made_s, t)
                ages.append(view.age_s)
            assert min(ages) >= 0.0
        finally:
            client.close()

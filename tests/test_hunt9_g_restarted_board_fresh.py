"""A board that restarted while the host was paused is live again as soon as its fresh telemetry flows.

The host stops reading (its process paused); the board resets during the pause. Its new boot has no offset
on the host's clock, so its samples read behind are dated by the earliest they can have been made (the
host's last read before the pause plus their uptime). That kept its *fresh* telemetry — made milliseconds
before it was read — dated as old as the time from the pause to the restart, for the whole
``CATCH_UP_S`` (0.5 s) of prompt reads: a live board shown stale (ages of up to the pause's length), and
the run's view of it blind. Now the session catches up once the samples come as fast as the board makes
them (``STEADY_S``), and a backlog read is still never dated later than the board made it.

Through the sans-IO session fed the board's framed bytes with injected time, restarts drawn across the
pause (Hypothesis), the pty keeping a drawn part of the pause.
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_board_link_beside_echo import connected
from test_board_link_beside_host_pause import JITTER_S, PERIOD_S, Board, read_promptly

STALE_AFTER_S = 0.25  # the host's stale bound
LIVE_WITHIN_S = 0.1  # fresh telemetry is dated by its read this long after the first fresh read at most


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    rate=st.floats(0.95, 1.05),
    pause_s=st.floats(0.5, 8.0),
    reset_in=st.floats(0.05, 0.95),
    kept=st.integers(0, 150),
    seed=st.integers(0, 999),
)
def test_a_restarted_boards_fresh_telemetry_is_live_soon_after_a_host_pause(
    rate, pause_s, reset_in, kept, seed
):
    """The host pauses ``pause_s``; the board restarts ``reset_in`` of the way into it; the pty kept the
    first ``kept`` frames of the pause. After the backlog the host reads the board's frames as they are
    made: each is never dated later than made, and from ``LIVE_WITHIN_S`` on it is live (younger than the
    stale bound) — not stale for 0.5 s after the host is back."""
    rng = random.Random(seed)
    s, _ = connected()
    old = Board(rate, 9_000.0)
    read_end = read_promptly(s, old, 0.01, 4.0, rng)
    resume = read_end + pause_s
    reset_at = read_end + reset_in * pause_s
    new = Board(rate, -rate * reset_at * 1000.0)
    made = [read_end + (i + 1) * PERIOD_S for i in range(int(pause_s / PERIOD_S))]
    backlog = [(old if t < reset_at else new).frame(t) for t in made][:kept]
    s.poll(resume)
    if backlog:
        s.feed(b"".join(backlog), resume, read_end)
        read_end = resume
    t = resume
    first = None
    while t < resume + 0.4:
        t += PERIOD_S
        now = t + rng.uniform(0.0, JITTER_S)
        s.poll(now)
        s.feed(new.frame(t), now, read_end)
        read_end = now
        first = now if first is None else first
        tel_t = s.telemetry_time
        assert tel_t is not None and tel_t <= t + JITTER_S + 0.002, (tel_t - t, "dated later than made")
        if now - first >= LIVE_WITHIN_S:
            assert now - tel_t <= STALE_AFTER_S, (
                f"fresh telemetry made {now - t:.3f} s before its read, {now - resume:.3f} s after the host "
                f"was back, dated {now - tel_t:.3f} s old"
            )

"""A new boot's backlog read in several chunks after a host pause is never dated live; a link that comes
back after a loss is not a late read.

* The host paused; the board reset during the pause; at the resume a pty hands the backlog over 4 KiB at
  a time, each chunk read at once after the one before. Only the first chunk was dated by the board's
  clock: from the second on the new boot's samples were dated by their receive time — telemetry seconds
  old shown as live. Through the sans-IO session fed the board's framed bytes with injected time
  (Hypothesis: pauses, reset moments, how much the pty kept, the chunk size).
* The reverse side: the late-read state survived a link loss. A board that hung, then was unplugged and
  plugged back seconds later: the first read of the new connection was "late" (the client's previous read
  ended before the loss), and the restarted board's fresh telemetry was dated by the earliest it could
  have been made — stale for up to ``CATCH_UP_S`` after it was back. Through the sans-IO session and
  through the client against ``firmware-sim`` behind a real pty (a restart of the emulator).
"""

from __future__ import annotations

import random
import time
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from sim_support import Sim, sims
from test_board_link_beside_echo import connected, hello_reply
from test_board_link_beside_host_pause import JITTER_S, PERIOD_S, Board, read_promptly

from hil.link.board import BoardClient, ClientConfig, StateEvent, TelemetryEvent
from hil.link.board.made_at import PROMPT_READ_S


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.generate],
)
@given(
    pause_s=st.floats(0.5, 6.0),
    reset_in=st.floats(0.0, 0.9),
    kept=st.integers(2, 200),
    first_ms=st.integers(0, 300),
    chunk=st.sampled_from([256, 1024, 4096]),
    seed=st.integers(0, 999),
)
def test_a_new_boots_backlog_read_in_chunks_is_never_dated_live(
    pause_s, reset_in, kept, first_ms, chunk, seed
):
    """The host pauses ``pause_s``; the board resets ``reset_in`` of the way into it; the pty kept the
    first ``kept`` frames of the pause and hands them over ``chunk`` bytes a read, the reads back to back
    (1 ms apart). After every read the telemetry held is dated no later than the board made it (within
    ``PROMPT_READ_S``, as any prompt read's) and never before the host's last read before the pause."""
    rng = random.Random(seed)
    s, _ = connected()
    old = Board(1.0, 9_000.0)
    read_end = read_promptly(s, old, 0.01, 6.0, rng)
    resume = read_end + pause_s
    reset_at = read_end + reset_in * pause_s
    new = Board(1.0, -reset_at * 1000.0)  # booted at reset_at
    made = [read_end + (i + 1) * PERIOD_S for i in range(int(pause_s / PERIOD_S))]
    frames = [
        (t, (old if t < reset_at else new).frame(t))
        for t in made
        if not reset_at <= t < reset_at + first_ms / 1e3
    ][:kept]
    data = b"".join(f for _, f in frames)
    ends = []  # the time each frame's last byte was read ... by offset in ``data``
    offset = 0
    for t, f in frames:
        offset += len(f)
        ends.append((offset, t))
    paused_from, waiting_since, now = read_end, read_end, resume
    for start in range(0, len(data), chunk):
        s.poll(now)
        s.feed(data[start : start + chunk], now, waiting_since)
        got = start + chunk
        newest = max((t for end, t in ends if end <= got), default=None)
        tel_t = s.telemetry_time
        if newest is not None:  # a prompt read's frames are dated by their receive time: at most this late
            assert tel_t is not None and paused_from <= tel_t <= newest + PROMPT_READ_S + JITTER_S, (
                f"read at {now - paused_from:.3f} s after the pause began ({start // chunk + 1}. chunk): the "
                f"newest telemetry, made {now - newest:.3f} s before, was dated {now - tel_t:.3f} s before"
            )
        waiting_since, now = now, now + 0.001


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    pause_s=st.floats(0.5, 4.0),
    away_s=st.floats(0.5, 6.0),
    first_ms=st.integers(20, 400),
    seed=st.integers(0, 999),
)
def test_a_board_back_after_a_link_loss_is_dated_by_its_receive_time(pause_s, away_s, first_ms, seed):
    """The host pauses ``pause_s`` and reads the first chunk of the backlog (old frames: the session is
    behind); the link is then lost, and ``away_s`` later the port opens again on a restarted board (the
    client passes the new connection's opening as the read's start: nothing older comes through a port
    opened anew). The new boot's telemetry, read promptly, is dated within the link's jitter of its
    receive time — fresh telemetry of a board back in hand is not held stale by a pause before the loss."""
    rng = random.Random(seed)
    s, board = connected()
    old = Board(1.0, 9_000.0)
    read_end = read_promptly(s, old, 0.01, 4.0, rng)
    resume = read_end + pause_s
    backlog = b"".join(old.frame(read_end + (i + 1) * PERIOD_S) for i in range(3))
    s.poll(resume)
    s.feed(backlog, resume, read_end)  # behind: the backlog is seconds old
    s.link_down(resume + 0.001, "the port went away")
    up = resume + away_s
    s.link_up(up)
    boot = up - first_ms / 1000.0  # the board restarted first_ms before the port opened
    new = Board(1.0, -boot * 1000.0)
    now = up + 0.01
    s.feed(board.encode(hello_reply())[1], now, up)
    waiting_since, t = now, now
    while t < up + 1.0:
        t += PERIOD_S
        now = t + rng.uniform(0.0, JITTER_S)
        s.poll(now)
        s.feed(new.frame(t), now, waiting_since)
        assert s.telemetry_time is not None and now - JITTER_S - PROMPT_READ_S <= s.telemetry_time <= now, (
            f"{t - up:.3f} s after the port opened: read at {now:.3f} s, dated {s.telemetry_time:.3f} s"
        )
        waiting_since = now
    assert s.counters.resets == 1


def test_a_restarted_board_back_on_its_pty_is_dated_by_its_receive_time(tmp_path: Path):
    """``firmware-sim`` killed and started again 2 s later on the same link path; the client's reader thread
    reconnects. Every sample of the new boot (its state changes, its telemetry) is dated within 0.1 s of
    its receive time: the client's last read before the loss ended seconds before, the first read of the
    new connection was taken for a late one, and the restarted board's first state (a Heartbeat's) was
    dated 3.7 s before it was read — within the outage, before the board was even started again."""
    link = tmp_path / "board"
    seen: list[tuple[str, float, float]] = []  # (what, read at, dated) of every sample after the loss
    client: BoardClient | None = None

    def on_event(event: object) -> None:
        assert client is not None
        if not client.session.counters.link_losses:
            return
        now = client.clock.now()
        if isinstance(event, TelemetryEvent):
            made = client.session.telemetry_time
            assert made is not None
            seen.append(("telemetry", now, made))
        elif isinstance(event, StateEvent):
            seen.append((f"state {event.new.name}", now, event.t))

    with sims(tmp_path) as boards:
        boards.append(Sim(tmp_path, link, "--units", "2"))
        client = BoardClient(str(link), config=ClientConfig(), on_event=on_event)
        try:
            client.connect()
            client.start()
            time.sleep(0.5)
            boards[-1].kill()
            time.sleep(2.0)
            boards.append(Sim(tmp_path, link, "--units", "2"))
            deadline = time.monotonic() + 10.0
            while sum(what == "telemetry" for what, _, _ in seen) < 20 and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            client.close()
    assert sum(what == "telemetry" for what, _, _ in seen) >= 20, (
        "the client took no telemetry of the new boot"
    )
    late = [(what, now - made) for what, now, made in seen if now - made > 0.1]
    assert not late, f"fresh samples of the restarted board dated seconds before their read: {late[:3]}"

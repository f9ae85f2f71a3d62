"""An outage opened by a board's reset starts when the board restarted, not when the host noticed.

The board hung; its MCU watchdog (0.1 s) restarted it, and it sent telemetry again before the host's stale
bound (0.25 s) passed: no ``stale`` fault came first. The reset was told at the new handshake's answer and
the outage opened there — "out for 0.02 s" for a board that had stopped 0.2 s before and restarted 0.07 s
before the host saw it (its own uptime said so). Now the reset says since when there was no board in hand
(``no_board_since``: the new boot's start, by its uptime), never earlier than the old boot was last heard
nor than the connection opened (time before the port first opened is in no outage).

In lockstep through the emulated board's own fault injection (``hang_at``, a short ``mcu_watchdog``) at
drawn moments; through the sans-IO session with drawn uptimes of the new boot, absurd ones among them.
"""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_board_faults import DT, _quick, _run
from test_board_link_beside_echo import connected, hello_reply, telemetry

from hil.link.board import BoardResetEvent


@settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(at=st.floats(3.0, 5.0), watchdog_s=st.floats(0.1, 0.14))
def test_a_reset_found_without_a_stale_fault_opens_its_outage_at_the_restart(
    tmp_path_factory, at, watchdog_s
):
    """The board hangs at ``at``; its watchdog restarts it ``watchdog_s`` later, before the host's stale
    bound: the outage the reset opens starts no later than the restart (within a telemetry period and a
    tick) and no earlier than the hang (the board was heard until then)."""
    sc = _quick(hang_at=[f"{at:.3f}"])
    sc = sc.with_changes(board_options={**sc.board_options, "mcu_watchdog": watchdog_s})
    result, _, events = _run(tmp_path_factory.mktemp("run"), sc, duration_s=at + 2.0)
    s = result.summary
    assert s["board_resets"] == 1, s["exit"]
    assert not any(f["kind"] == "stale" for f in s["faults"]), s["faults"]
    reset = next(e for e in events if e["kind"] == "board_reset")
    outage = s["outages"][0]
    restart = at + watchdog_s
    assert at - 2 * DT <= outage["start"] <= restart + 2 * DT, (
        f"the board hung at {at:.3f} s and restarted at {restart:.3f} s; its reset (told at "
        f"{reset['t']:.3f} s) opened an outage at {outage['start']:.3f} s"
    )
    assert outage["recovered"] and outage["duration_s"] >= outage["end"] - restart - 2 * DT


@settings(max_examples=200, deadline=None)
@given(
    heard_s=st.floats(0.5, 50.0),
    gap_s=st.floats(0.0, 0.3),
    uptime_ms=st.one_of(st.integers(0, 400), st.integers(0, 10**7)),
    old_ms=st.integers(1_000, 10**7),
)
def test_a_resets_no_board_since_is_the_restart_clamped_to_what_was_heard(heard_s, gap_s, uptime_ms, old_ms):
    """The old boot last heard at ``heard_s`` (uptime ``old_ms``); ``gap_s`` later a sample of a new boot
    (uptime ``uptime_ms``, going back) is read. The reset's ``no_board_since`` is the new boot's start
    by its uptime, never before the old boot was last heard nor after the sample's read — whatever the
    uptime says (one of hours put the start before the run began)."""
    uptime_ms %= old_ms  # a reset: its count went back
    s, framer = connected()
    s.poll(heard_s)
    s.feed(framer.encode(telemetry(old_ms))[1], heard_s, heard_s - 0.02)
    now = heard_s + gap_s
    s.poll(now)
    s.feed(framer.encode(telemetry(uptime_ms))[1], now, max(heard_s, now - 0.01))  # reading all along
    s.poll(now + 0.01)
    s.feed(framer.encode(hello_reply())[1], now + 0.01, now)
    resets = [e for e in s.take_events() if isinstance(e, BoardResetEvent)]
    assert len(resets) == 1
    since = resets[0].no_board_since
    assert since is not None and heard_s <= since <= now
    if heard_s <= now - uptime_ms / 1000.0:
        assert since == now - uptime_ms / 1000.0

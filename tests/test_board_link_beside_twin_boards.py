"""Two boards answering as one — a second board on a CAN bus configured with this one's node id, on a bus
whose interface names no sender (socketcan, pcan: only ``udp_multicast`` says who sent a frame) — are told
apart by their boot ids: a board draws its id anew at each boot, so one board's replaced ids never come
back, while twins interleave theirs many times a second. Each change was taken for a reset: hundreds of
them, the "board" re-armed each time (both boards commanded), until the run ended "lost" with nothing
naming the cause. The session now raises a :class:`LinkError` naming both ids. A single board whose ids
do come back now and then (an emulator restarted with its seed draws them again) is not taken for twins.
Through the sans-IO session fed both boards' framed heartbeats with injected time."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_board_link_beside_echo import connected, hello_reply

from hil.link.board.session import TWIN_RETURNS, TWIN_WINDOW_S
from protocol.errors import LinkError
from protocol.frame import Framer
from protocol.messages import BoardState, Heartbeat

A, B = 0x1234_5678, 0x9ABC_DEF0


def heartbeat(board: Framer, uptime_ms: int, boot_id: int) -> bytes:
    return board.encode(Heartbeat(time_ms=uptime_ms, state=BoardState.DISARMED, boot_id=boot_id))[1]


@settings(max_examples=60, deadline=None)
@given(
    period_s=st.floats(0.01, 0.2),  # each board's heartbeat period
    offset=st.floats(0.0, 1.0),  # the second board's phase in that period
    uptimes=st.tuples(st.integers(0, 10**6), st.integers(0, 10**6)),
)
def test_two_boards_heard_as_one_end_the_session_with_an_error_naming_both(period_s, offset, uptimes):
    s, _ = connected()
    boards = (Framer(), Framer())
    t = 0.02
    with pytest.raises(LinkError, match="two boards answer as one") as raised:
        for k in range(200):
            for i, boot_id in enumerate((A, B)):
                at = t + k * period_s + (offset * period_s if i else 0.0)
                s.poll(at)
                s.feed(heartbeat(boards[i], uptimes[i] + round(k * period_s * 1000), boot_id), at)
    assert f"{A:#010x}" in str(raised.value) and f"{B:#010x}" in str(raised.value)
    assert k * period_s <= TWIN_RETURNS * period_s + TWIN_WINDOW_S  # said within a few alternations


@settings(max_examples=30, deadline=None)
@given(
    # a return each half cycle: TWIN_RETURNS of them span more than TWIN_WINDOW_S
    restart_every_s=st.floats(2 * TWIN_WINDOW_S / (TWIN_RETURNS - 1) + 0.05, 30.0),
    restarts=st.integers(1, 12),
)
def test_one_board_restarted_with_its_seed_again_and_again_is_no_twin(restart_every_s, restarts):
    """An emulator restarted with its seed boots with A, reboots with B, and after its process restarts
    draws A then B again: its ids come back once per restart — a reset each, never twins."""
    s, board = connected()
    t = 0.02
    for _ in range(restarts):
        for boot_id in (A, B):
            board = Framer()
            s.poll(t)
            s.feed(board.encode(hello_reply())[1], t)
            for k in range(5):
                at = t + 0.05 * (k + 1)
                s.poll(at)
                s.feed(heartbeat(board, 50 * (k + 1), boot_id), at)
            t += restart_every_s / 2
    assert s.boot_id in (A, B)

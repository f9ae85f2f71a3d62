"""A board outage ends when the host has the board back, not when the phone comes back.

The board hung and its watchdog reset it; the host re-armed it through the protocol; meanwhile the phone
paused. The outage's end (``board_back``, ``summary.json``'s ``outages``, the printed "back at …") waited
for the phone as well: "back at 2.948 s (stale, reset)" for a board live and armed again at 1.988 s — the
extra second was the phone's gap, which is recorded on its own (``phone_gap_list``) with its own times.
In lockstep through the emulated board's own fault injection (``hang_at``) and the simulated phone's
(``phone_gap``), the phone's pause drawn at several moments around the board's outage.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_board_faults import DT, _quick, _run

from hil.runtime.faults import BoardLink
from protocol.messages import BoardState


@pytest.mark.parametrize(
    ("gap_at", "gap_s"),
    [(4.3, 1.5), (4.05, 2.5), (4.6, 1.0), (3.9, 3.0)],  # the phone pauses during the board's outage
)
def test_a_board_outage_ends_at_the_boards_return_whatever_the_phone(tmp_path, gap_at, gap_s):
    """Board hung at 4.0 s (watchdog reset, re-armed); the phone paused ``gap_s`` from ``gap_at``. The
    outage ends at the first control tick with the board live and ARMED after the host's re-arm (the host
    has the board in hand) — not at the phone's return; the phone's gap has its own start and end."""
    result, tel, events = _run(
        tmp_path, _quick(hang_at=["4.0"], phone_gap=[f"{gap_at}:{gap_s}"]), duration_s=14.0
    )
    s = result.summary
    assert s["board_resets"] == 1 and s["rearms"] == 1, s["exit"]
    rearmed = next(e["t"] for e in events if e["kind"] == "rearmed")
    t = tel["t"]
    armed_live = (
        (t >= rearmed - 1e-9)
        & (tel["board_link"] == int(BoardLink.LIVE))
        & (tel["board_state"] == int(BoardState.ARMED))
    )
    board_back_at = float(t[np.argmax(armed_live)])
    outage = s["outages"][0]
    assert outage["recovered"] and "reset" in outage["causes"]
    assert outage["end"] == pytest.approx(board_back_at, abs=1e-9), (
        f"the board was live and armed again at {board_back_at:.3f} s, its outage said back at "
        f"{outage['end']:.3f} s (the phone back at {s['phone_gap_list'][0]['end']:.3f} s)"
    )
    gap = s["phone_gap_list"][0]
    assert gap["recovered"] and gap["end"] == pytest.approx(gap_at + gap_s, abs=2 * DT)
    back = next(e for e in events if e["kind"] == "board_back")
    assert back["t"] == pytest.approx(board_back_at, abs=1e-9)


@settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(
    fault=st.sampled_from(["hang_at", "brownout_at", "stall"]),
    at=st.floats(3.5, 6.0),
    gap_after=st.floats(-0.3, 0.8),  # the phone's pause begins this long after the board's fault
    gap_s=st.floats(0.8, 3.0),
)
def test_drawn_board_faults_beside_a_phone_pause_end_at_the_boards_return(
    tmp_path_factory, fault, at, gap_after, gap_s
):
    """A board fault at a drawn moment (a hang and its watchdog reset, a brown-out, a link stall shorter
    than the board's watchdog) and a phone pause drawn around it: every outage recovered ends at the first
    tick after its start with the board live and ARMED and no re-arm still to come — the first after the
    last ``rearmed`` before it — never at the phone's return."""
    spec = f"{at:.3f}:0.15" if fault == "stall" else f"{at:.3f}"
    gap = f"{at + gap_after:.3f}:{gap_s:.3f}"
    tmp_path = tmp_path_factory.mktemp("run")
    result, tel, events = _run(tmp_path, _quick(**{fault: [spec], "phone_gap": [gap]}), duration_s=14.0)
    s = result.summary
    t = tel["t"]
    armed_live = (tel["board_link"] == int(BoardLink.LIVE)) & (tel["board_state"] == int(BoardState.ARMED))
    rearmed = [e["t"] for e in events if e["kind"] == "rearmed"]
    for outage in s["outages"]:
        if not outage["recovered"]:
            continue
        start, end = outage["start"], outage["end"]
        last_rearm = max((r for r in rearmed if start - 1e-9 <= r <= end + 1e-9), default=start)
        back = armed_live & (t >= last_rearm - 1e-9)
        assert back.any()
        board_back_at = float(t[np.argmax(back)])
        assert end == pytest.approx(board_back_at, abs=1e-9), (fault, spec, gap, outage, s["phone_gap_list"])

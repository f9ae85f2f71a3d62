"""A phone gap opens when the phone stopped being fresh, not at the control tick that noticed it.

A board's stale outage opens ``stale_after_s`` after its last telemetry (the moment it stopped being
live); a phone gap opened at the tick that found it — a tick late at best, as late as the tick after a
host stall — so its start, its ``gap_s`` and the phone's lost bound counted from it said the phone was out
for less than it was. Now the gap opens ``stale_after_s`` after its needed samples were last heard
(``since`` in its ``phone_gap`` record), never after the tick that found it.

In lockstep against the emulated board and its simulated phone, gaps at drawn moments across the run.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_board_faults import _quick, _run

STALE_AFTER_S = 0.25  # the host's stale bound (RunOptions' default)


@settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(at=st.floats(2.0, 11.0), gap_s=st.floats(0.5, 1.5))
def test_a_phone_gap_opens_when_the_phone_stopped_being_fresh(tmp_path_factory, at, gap_s):
    """The phone pauses at ``at`` for ``gap_s``: the gap in the summary starts at its record's ``since``
    plus the stale bound (no later than the tick that noticed it), and its ``phone_back`` says the gap's
    length from there."""
    result, _, events = _run(
        tmp_path_factory.mktemp("run"),
        _quick(phone_gap=[f"{at:.3f}:{gap_s:.3f}"]),
        duration_s=at + gap_s + 3.0,
    )
    s = result.summary
    gap = next(e for e in events if e["kind"] == "phone_gap")
    back = next(e for e in events if e["kind"] == "phone_back")
    episode = s["phone_gap_list"][0]
    assert episode["start"] == pytest.approx(gap["since"] + STALE_AFTER_S, abs=1e-9), (episode, gap)
    assert episode["start"] <= gap["t"]
    assert back["since"] == pytest.approx(episode["start"], abs=1e-9)
    assert back["gap_s"] == pytest.approx(back["t"] - episode["start"], abs=1e-9)
    assert s["exit"] == "completed", s["exit"]

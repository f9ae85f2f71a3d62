"""The host's view of a board that falls silent, dated from the board's own last word at every phase of a
run — its handshake, the first Arm's wait, the still window, the spin-up, the slew — not from the control
tick that happened to look (:meth:`hil.runtime.watch.BoardWatch.view`).

What broke: a board that hung between its handshake and the run's first Arm (silent from 0.100 s) was
counted silent from the first control tick, after the Arm's 0.5 s wait: its ``stale`` fault and outage
began at 0.86 s, not 0.35 s (its handshake + the 0.25 s stale bound), so a board never back was declared
lost 0.5 s late and its outage said 0.5 s shorter than the board's silence.

Faults through the emulator's own injection (``hang_at``), with an MCU watchdog slower than the stale
bound (``mcu_watchdog``) so the silence is told by the view, not by a reset; lockstep clocks.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.record import RunRecorder
from tests.fault_support import faulted_run_settings, short_scenario

STALE_AFTER_S = 0.25  # the host's stale bound (the board's link timeout)
TELEMETRY_S = 0.02  # the emulator's telemetry period at 50 Hz
HANDSHAKE_T = 0.100001  # when the emulated board answers the first handshake (lockstep)


def _run_hung(at: float, watchdog_s: float = 2.0, recover_within_s: float | None = None) -> RunRecorder:
    """The short scenario, its board's MCU hung at ``at`` (s) until its watchdog (``watchdog_s``) resets
    it; recorded in memory."""
    sc = short_scenario()
    options: dict[str, Any] = dict(sc.fault_options)
    options.update(hang_at=[repr(at)], mcu_watchdog=[repr(watchdog_s)])
    sc = sc.with_changes(fault_options=options)
    recorder = RunRecorder(sc.n_units)
    extra = {} if recover_within_s is None else {"recover_within_s": recover_within_s}
    run(sc, RunOptions(out_root=None, observer=recorder, rows_to_observer=True, **extra))
    return recorder


def _first_stale(recorder: RunRecorder) -> tuple[dict[str, Any], dict[str, Any]]:
    s = recorder.summary
    stale = next(f for f in s["faults"] if f["kind"] == "stale")
    outage = next(o for o in s["outages"] if "stale" in o["causes"])
    return stale, outage


def test_a_board_hung_before_the_first_arm_is_stale_from_its_handshake_not_the_first_tick():
    """Hung 0.2 ms after it answered the handshake: its silence runs from 0.100 s, so it is stale from
    0.350 s — before, from 0.86 s (the first control tick after the Arm's 0.5 s wait, plus the bound)."""
    recorder = _run_hung(0.1002)
    stale, outage = _first_stale(recorder)
    assert stale["t"] == pytest.approx(HANDSHAKE_T + STALE_AFTER_S, abs=1e-6), stale
    assert outage["start"] == pytest.approx(HANDSHAKE_T + STALE_AFTER_S, abs=1e-6), outage
    assert stale["tel_age_ms"] is None  # no telemetry ever came: never shown as a number


@faulted_run_settings(10)
@given(
    at=st.one_of(
        st.floats(0.1002, 9.5),
        st.sampled_from([0.1002, 0.35, 0.59, 0.6, 0.601, 0.62, 2.62, 4.2]),  # handshake, Arm, phase edges
    )
)
def test_a_board_silent_at_any_phase_is_stale_the_bound_after_its_last_word(at):
    """A hang at a drawn moment (the phase changes among them): the ``stale`` fault and the outage it
    opens start the stale bound after the board's last word — its last telemetry before the hang (one
    telemetry period at most before it), or its handshake — whatever the host was doing then."""
    recorder = _run_hung(round(at, 4))
    at = round(at, 4)
    stale, outage = _first_stale(recorder)
    last_word_lo = max(at - TELEMETRY_S, HANDSHAKE_T) - 1e-6  # the board speaks every 20 ms, or answered
    assert last_word_lo + STALE_AFTER_S <= stale["t"] <= at + STALE_AFTER_S + 1e-6, (at, stale)
    assert outage["start"] == pytest.approx(stale["t"], abs=1e-9), (at, outage, stale)


def test_a_board_never_back_is_lost_the_bound_after_its_silence_began():
    """A board hung from its handshake on, its watchdog slower than the run's bound: lost 1 s after it
    went stale (0.35 s), its outage as long as it says — not dated from the first control tick."""
    recorder = _run_hung(0.1002, watchdog_s=8.0, recover_within_s=1.0)
    s = recorder.summary
    assert s["exit"].startswith("lost: board lost at t=0.350 s for 1.0 s (stale)"), s["exit"]
    rows = recorder.rows()
    assert float(rows["t"][-1]) == pytest.approx(0.350001 + 1.0, abs=0.03)

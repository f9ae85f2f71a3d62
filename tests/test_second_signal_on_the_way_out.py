"""A second signal wherever it lands on the run's way out: the board the run armed is disarmed, and said.

CI's drawn moments (tests/test_run_ends_signals.py) twice found a run interrupted with its board armed,
a SIGTERM 5.5 µs after the SIGINT, that sent no Disarm and said none: the second interrupt was raised
on the entry of the ExitStack callback that disarms the board (before its ``try``), or between two of
the ExitStack's callbacks, and so skipped them. From the first interrupt on, the next signal is now
held (:mod:`hil.runtime.held_signals`).

Here the moments are not left to the scheduler: the run goes in-process, in lockstep, under hil's own
signal handlers; the first signal is raised at a drawn simulated time, and the second at a drawn
function call after it (tests/signal_support.py) — the first few dozen calls are the unwinding, the
ExitStack and the Disarm's start, the ones after the Disarm's wait, the link's close and the ending's
writing.
"""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import pytest
from fault_support import faulted_run_settings
from hypothesis import given
from hypothesis import strategies as st
from observer_support import SilentObserver
from signal_support import SecondSignal

from hil.cli._signals import interrupts_raise
from hil.runtime.held_signals import STOP_SIGNALS
from hil.runtime.loop import RunOptions, run
from hil.runtime.runlog import read_events
from hil.scenario import load_scenario

WAY_OUT_CALLS = 14_000  # function calls from the first interrupt to run()'s return, about (a default run)
FIRST_CALLS = 40  # the first calls after the first interrupt: the unwinding, the ExitStack, the Disarm


class FirstSignal(SilentObserver):
    """The run's observer that raises ``first`` at the run's simulated time ``first_at``, the second
    signal ``then`` (:class:`SecondSignal`) counting calls from there."""

    def __init__(self, first: int, first_at: float, then: SecondSignal) -> None:
        self.first, self.first_at, self.then = first, first_at, then
        self.sent = False

    def tick(self, t: float) -> None:
        if t >= self.first_at and not self.sent:
            self.sent = True
            self.then.raise_first(self.first)


def _run_and_check(out: Path, first: int, first_at: float, second: int, at_call: int) -> None:
    """The run with its two signals, and what its run directory must say: interrupted by the first, its
    summary whole, its board — armed at the interrupt — disarmed once and said (``disarmed``, the first's
    reason), ``final_disarm`` confirmed."""
    second_signal = SecondSignal(second, at_call)
    first_signal = FirstSignal(first, first_at, second_signal)
    try:
        with interrupts_raise():
            result = run(load_scenario(), RunOptions(out_root=out, observer=first_signal, duration_s=4.0))
    finally:
        sys.settrace(None)
    assert first_signal.sent
    assert second_signal.sent_second or at_call > FIRST_CALLS
    exits = {f"interrupted ({name})" for name in second_signal.named(first)}
    assert result.summary["exit"] in exits
    assert result.run_dir is not None
    summary = json.loads((Path(result.run_dir) / "summary.json").read_text())
    assert summary["exit"] == result.summary["exit"]
    events, bad = read_events(Path(result.run_dir) / "events.jsonl")
    assert bad == 0
    kinds = [e["kind"] for e in events]
    disarms = [(e["kind"], e["reason"]) for e in events if e["kind"] in ("disarmed", "disarm_failed")]
    if "armed" in kinds:
        assert disarms == [("disarmed", summary["exit"])], (at_call, second_signal.calls, kinds[-6:])
        assert summary["final_disarm"]["ok"] is True, summary["final_disarm"]
    else:
        assert disarms == [], disarms


@pytest.mark.parametrize("at_call", range(1, FIRST_CALLS + 1))
def test_a_second_signal_on_any_of_the_first_calls_of_the_way_out(tmp_path, at_call):
    """The second signal on each of the first calls after the first interrupt: its handler and its
    exception, the ExitStack's entry, the callbacks before the disarming one, its entry, the Disarm's
    start (the calls CI's 5.5 µs fell on), mid-slew."""
    _run_and_check(tmp_path, signal.SIGINT, 5.8, signal.SIGTERM, at_call)


@faulted_run_settings(20)
@given(
    first=st.sampled_from(STOP_SIGNALS),
    first_at=st.floats(1.0, 7.0),  # warm-up, spin-up at 2.1 s, the slew from 3.7 s
    second=st.sampled_from(STOP_SIGNALS),
    at_call=st.integers(1, WAY_OUT_CALLS),
)
def test_a_second_signal_anywhere_on_the_way_out_leaves_the_board_disarmed_and_said(
    tmp_path_factory, first, first_at, second, at_call
):
    """Any signal at any moment of the run, any second one at any call of its way out (the Disarm's wait,
    the link's close, the ending's writing included)."""
    _run_and_check(tmp_path_factory.mktemp("way_out"), first, first_at, second, at_call)

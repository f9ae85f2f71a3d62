"""A second signal wherever it lands on the run's way out: the board the run armed is disarmed, and said.

CI's drawn moments (tests/test_run_ends_signals.py) twice found a run interrupted with its board armed,
a SIGTERM 5.5 µs after the SIGINT, that sent no Disarm and said none: the second interrupt was raised
on the entry of the ExitStack callback that disarms the board (before its ``try``), or between two of
the ExitStack's callbacks, and so skipped them. From the first interrupt on, the next signal is now
held (:mod:`hil.runtime.held_signals`).

Here the moments are not left to the scheduler: the run goes in-process, in lockstep, under hil's own
signal handlers; the first signal is raised at a drawn simulated time, and the second at a drawn
function call after it — the first few dozen calls are the unwinding, the ExitStack and the Disarm's
start, the ones after the Disarm's wait, the link's close and the ending's writing.
"""

from __future__ import annotations

import json
import signal
import sys
from collections.abc import Mapping
from pathlib import Path
from types import FrameType
from typing import Any

import pytest
from fault_support import faulted_run_settings
from hypothesis import given
from hypothesis import strategies as st

from hil.cli._signals import interrupts_raise
from hil.runtime.held_signals import STOP_SIGNALS
from hil.runtime.loop import RunOptions, run
from hil.runtime.runlog import read_events
from hil.scenario import load_scenario

WAY_OUT_CALLS = 14_000  # function calls from the first interrupt to run()'s return, about (a default run)
FIRST_CALLS = 40  # the first calls after the first interrupt: the unwinding, the ExitStack, the Disarm


class SecondSignal:
    """Raises ``second`` at the ``at_call``-th function call after ``first`` was raised (at simulated time
    ``first_at``, from the observer's tick), through a trace function installed by the first's handler."""

    def __init__(self, first: int, first_at: float, second: int, at_call: int) -> None:
        self.first, self.first_at = first, first_at
        self.second, self.at_call = second, at_call
        self.calls = 0
        self.sent_first = False
        self.sent_second = False

    # ------------------------------------------------------------- the observer
    def started(self, start: Any) -> None:
        pass

    def row(self, row: Mapping[str, Any]) -> None:
        pass

    def event(self, record: Mapping[str, Any]) -> None:
        pass

    def finished(self, summary: Mapping[str, Any]) -> None:
        pass

    def tick(self, t: float) -> None:
        if t >= self.first_at and not self.sent_first:
            self.sent_first = True
            signal.raise_signal(self.first)

    # ------------------------------------------------------------- the second signal
    def handler_before(self, handler: Any) -> Any:
        """hil's handler ``handler`` for the first signal, with the trace started just before it raises."""

        def first_handler(signum: int, frame: FrameType | None) -> None:
            if signum == self.first and not self.sent_second and sys.gettrace() is None:
                sys.settrace(self._trace)
            handler(signum, frame)

        return first_handler

    def _trace(self, frame: FrameType, event: str, arg: object) -> None:
        if event == "call" and not self.sent_second:
            self.calls += 1
            if self.calls >= self.at_call:
                self.sent_second = True
                sys.settrace(None)
                signal.raise_signal(self.second)  # handled at the next instruction that checks: the call's


def _run_and_check(out: Path, first: int, first_at: float, second: int, at_call: int) -> None:
    """The run with its two signals, and what its run directory must say: interrupted by the first, its
    summary whole, its board — armed at the interrupt — disarmed once and said (``disarmed``, the first's
    reason), ``final_disarm`` confirmed."""
    signals = SecondSignal(first, first_at, second, at_call)
    with interrupts_raise():
        hil_handler = signal.getsignal(first)
        signal.signal(first, signals.handler_before(hil_handler))
        try:
            result = run(load_scenario(), RunOptions(out_root=out, observer=signals, duration_s=4.0))
        finally:
            sys.settrace(None)
    assert signals.sent_first
    name = signal.Signals(first).name
    assert result.summary["exit"] == f"interrupted ({name})"
    assert result.run_dir is not None
    summary = json.loads((Path(result.run_dir) / "summary.json").read_text())
    assert summary["exit"] == f"interrupted ({name})"
    events, bad = read_events(Path(result.run_dir) / "events.jsonl")
    assert bad == 0
    kinds = [e["kind"] for e in events]
    disarms = [(e["kind"], e["reason"]) for e in events if e["kind"] in ("disarmed", "disarm_failed")]
    if "armed" in kinds:
        assert disarms == [("disarmed", f"interrupted ({name})")], (at_call, signals.calls, kinds[-6:])
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

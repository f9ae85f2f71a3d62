"""A second signal wherever it lands while ``hil calibrate`` puts an interrupted board back to rest.

The run's way out lost its Disarm to a second signal microseconds after the first
(tests/test_second_signal_on_the_way_out.py); the calibration's way out (``_bench``: the outputs to
their base pulses, Disarm, SETPOINT mode, the state said) had the same windows: a second interrupt on
the entry of the function that puts the board to rest skipped it, and nothing said so. From the first
interrupt on, the next signal is now held there too; a third gives the rest up, said.

In-process, in lockstep on the built-in emulator, under hil's own handlers: the first SIGINT when the
sweep prints its fourth step, the second at a chosen function call after it (tests/signal_support.py).
"""

from __future__ import annotations

import contextlib
import io
import signal
import sys
from pathlib import Path

import pytest
from fault_support import faulted_run_settings
from hypothesis import given
from hypothesis import strategies as st
from signal_support import SecondSignal

from hil.cli import main
from hil.runtime.held_signals import STOP_SIGNALS

PORT = "emu://?units=2"
SWEEP = ["--directions", "up", "--step", "50", "--settle", "0.2", "--settle-window", "0.3"]
AT_REST = (
    "hil calibrate: the board was left DISARMED in SETPOINT mode (no ESC being taught), its outputs at "
    "rest: unit 0 gimbal 1500 us, rotor 1000 us; unit 1 gimbal 1500 us, rotor 1000 us"
)
FIRST_CALLS = 40  # the first calls after the interrupt: the unwinding, the partial CSV, the rest's start
WAY_OUT_CALLS = 6_000  # about all of them, to the command's end


class InterruptAt(io.StringIO):
    """The command's standard output: raises the first signal ``first`` once ``text`` is printed, the
    second ``then`` (:class:`SecondSignal`) counting calls from there."""

    def __init__(self, text: str, first: int, then: SecondSignal) -> None:
        super().__init__()
        self.text, self.first, self.then = text, first, then
        self.sent = False

    def write(self, s: str) -> int:
        n = super().write(s)
        if not self.sent and self.text in self.getvalue():
            self.sent = True
            self.then.raise_first(self.first)
        return n


def _sweep_interrupted_twice(tmp_path: Path, second: int, at_call: int) -> None:
    """A sweep interrupted at its fourth step, a second signal at call ``at_call`` after: the status and
    the words of the first signal (:meth:`SecondSignal.named`), the board put to rest and said, the
    partial CSV kept."""
    second_signal = SecondSignal(second, at_call)
    out = InterruptAt("rotor sweep 4/21", signal.SIGINT, second_signal)
    err = io.StringIO()
    argv = ["calibrate", "sweep", "--port", PORT, "--unit", "0", "--out-dir", str(tmp_path), *SWEEP]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(argv)
    finally:
        sys.settrace(None)
    said = err.getvalue()
    assert out.sent
    assert second_signal.sent_second or at_call > FIRST_CALLS
    named = second_signal.named(signal.SIGINT)
    assert status in {128 + signal.Signals[name] for name in named}, said
    assert AT_REST in said, (at_call, second_signal.calls, said)
    assert any(said.rstrip().endswith(f"hil calibrate: interrupted ({name})") for name in named), said
    assert "marked '# status: partial'" in out.getvalue()


@pytest.mark.parametrize("at_call", range(1, FIRST_CALLS + 1))
def test_a_second_signal_on_any_of_the_first_calls_still_puts_the_board_to_rest(tmp_path, at_call):
    _sweep_interrupted_twice(tmp_path, signal.SIGTERM, at_call)


@faulted_run_settings(15)
@given(second=st.sampled_from(STOP_SIGNALS), at_call=st.integers(1, WAY_OUT_CALLS))
def test_a_second_signal_anywhere_on_the_way_out_still_puts_the_board_to_rest(
    tmp_path_factory, second, at_call
):
    _sweep_interrupted_twice(tmp_path_factory.mktemp("sweep"), second, at_call)

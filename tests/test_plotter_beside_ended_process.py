"""``hil run``'s drawing process (:class:`hil.cli.run.Plotter`, a real ``python -m hil.cli._plotter``) ended
before the run hands it its directory — killed, out of memory — at drawn moments of its life: the run's
end says the figures were not drawn and why, never a BrokenPipeError's traceback after a run that had
completed."""

from __future__ import annotations

import os
import signal
import time

import pytest

from hil.cli.run import Plotter


@pytest.mark.parametrize("after_s", [0.0, 0.05, 0.4, 1.5])
@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGTERM])
def test_a_drawing_process_gone_before_the_run_dir_is_handed_over_is_said(tmp_path, after_s, how):
    plotter = Plotter()
    time.sleep(after_s)  # at its start, in its imports, warming, waiting on its stdin
    os.killpg(plotter.process.pid, how)
    plotter.process.wait(timeout=30)
    plotter.draw(tmp_path)  # was: BrokenPipeError
    said = plotter.wait()
    assert said == f"plots: the drawing process was ended by {how.name}"


def test_a_drawing_process_ended_by_an_unnamed_signal_says_its_number(tmp_path):
    plotter = Plotter()
    number = signal.SIGRTMIN + 3
    if number in {s.value for s in signal.Signals}:
        pytest.skip(f"signal {number} has a name on this system")
    os.killpg(plotter.process.pid, number)
    plotter.process.wait(timeout=30)
    plotter.draw(tmp_path)
    assert plotter.wait() == f"plots: the drawing process was ended by signal {number}"

"""``hil replay LOG --port URL`` interrupted just after its run ended — SIGINT, SIGTERM or SIGHUP while the
run directory's plots are drawn — ends as ``hil run`` does (docs/faults.md, "hil run exit status", which
``hil replay --port`` shares): status 1, the run's summary printed, the plots said to be undone with the
command that draws them, no traceback.

Before: the interrupt escaped the drive (its plots were drawn in its own process, outside every
``except``): status 128 + the signal, the completed run's summary never printed, nothing said of its
plots. Real processes: ``python -m hil replay`` against the in-process board (lockstep: the run itself
takes a fraction of a second), the signal sent once its ``summary.json`` exists, after a drawn delay.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "fixtures" / "logs" / "simulated_testbed_4s.csv"
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _summary_written(out: Path, proc: subprocess.Popen[str], timeout: float = 120.0) -> Path:
    """The run directory once its summary.json is there (the run has ended; its plots are next)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = list(out.glob("*/summary.json"))
        if found:
            return found[0].parent
        assert proc.poll() is None, f"ended {proc.returncode} before its summary: {proc.communicate()}"
        time.sleep(0.005)
    raise AssertionError(f"no summary.json within {timeout} s")


@settings(max_examples=3, deadline=None)
@given(signum=st.sampled_from(SIGNALS), delay=st.floats(0.0, 0.3))
def test_an_interrupt_while_the_plots_are_drawn_ends_as_hil_runs_does(tmp_path_factory, signum, delay):
    tmp = tmp_path_factory.mktemp("plots")
    out = tmp / "runs"
    argv = ["replay", str(LOG), "--port", "emu://?units=4&telemetry_rate=50", "--out", str(out)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil", *argv],
        cwd=tmp,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        run_dir = _summary_written(out, proc)
        time.sleep(delay)
        proc.send_signal(signum)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["exit"] == "completed"  # the run had ended on its own; the interrupt came after it
    assert "Traceback" not in stderr, stderr
    assert proc.returncode == 1, (proc.returncode, stderr)
    assert "exit              completed" in stdout and f"run directory: {run_dir}" in stdout
    name = signal.Signals(signum).name
    assert f"hil replay: interrupted ({name})" in stderr and "run ended" in stderr, stderr
    assert f"hil report {run_dir}" in stderr  # how to draw what was left undone

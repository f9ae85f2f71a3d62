"""Every ``hil`` command, not only ``hil run``, ends on SIGHUP as on Ctrl-C; a signal that comes as a
command exits never turns a finished command into a killed one; and a run directory's files that are not
files, or a ``--pace`` slower than a thousandth of real time, are typed errors naming them.

Before: ``hil replay`` (and ``hil calibrate``, ``hil montecarlo``) died on SIGHUP with no summary; a
second Ctrl-C landing while the interpreter exited after a run had written its summary gave status 130
(or a KeyboardInterrupt traceback from an exit hook); ``hil report`` of a run whose ``events.jsonl`` was
a link to ``/dev/zero`` read it for ever; ``hil run --pace 1e-300`` ended in an OverflowError traceback.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "fixtures" / "logs" / "simulated_testbed_4s.csv"
WAIT_S = 120.0


def _hil(*args: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hil", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _line_with(proc: subprocess.Popen[str], text: str) -> None:
    """Read ``proc``'s stdout until a line holding ``text`` (the process still running or just ended)."""
    assert proc.stdout is not None
    deadline = time.monotonic() + WAIT_S
    for line in proc.stdout:
        if text in line:
            return
        assert time.monotonic() < deadline, f"no {text!r} within {WAIT_S} s"
    raise AssertionError(f"{proc.args} ended without printing {text!r}")


def test_sighup_ends_a_paced_replay_as_ctrl_c_does(tmp_path):
    """``hil replay --paced`` (the log's clock, in real time) is in its loop; its terminal closes."""
    proc = _hil(
        "replay", str(LOG), "--paced", "--progress", "--no-plots", "--out", str(tmp_path / "o"), cwd=tmp_path
    )
    try:
        time.sleep(1.5)  # imports done, the paced loop under way (the log is 4 s long)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGHUP)
        _, err = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGHUP, err
    assert "interrupted (SIGHUP)" in err and "Traceback" not in err


@settings(max_examples=8, deadline=None)
@given(delay_s=st.floats(0.0, 0.15), twice=st.booleans())
def test_a_signal_as_a_finished_run_exits_keeps_its_status(tmp_path_factory, delay_s, twice):
    """A completed run signalled a drawn moment after it printed its run directory (its summary on disk,
    the command reporting or the interpreter exiting): a status that says so, never death by the signal
    or a traceback."""
    cwd = tmp_path_factory.mktemp("late")
    proc = _hil("run", "--no-plots", "--duration", "1", "--out", str(cwd / "runs"), cwd=cwd)
    try:
        _line_with(proc, "run directory:")
        time.sleep(delay_s)
        for _ in range(1 + twice):
            try:
                proc.send_signal(signal.SIGINT)
            except ProcessLookupError:
                break
            time.sleep(0.002)
        out, err = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # 0: the signal came as the interpreter exited; 1: while ``hil run`` still reported (its "interrupted
    # after the run ended"); 130: as the command returned, said "interrupted". Never killed by it (-2).
    assert proc.returncode in (0, 1, 130), err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    if proc.returncode:  # the rest of its stdout beside: a status of the run's own would show there
        assert "interrupted (SIGINT)" in err, (proc.returncode, err[-1500:], out[-1500:])


@pytest.mark.parametrize("name", ["events.jsonl", "telemetry.csv"])
@pytest.mark.parametrize("kind", ["a link to /dev/zero", "a FIFO"])
def test_a_run_directory_file_that_is_no_file_is_an_error_naming_it(tmp_path, name, kind):
    run = tmp_path / "run"
    run.mkdir()
    (run / "telemetry.csv").write_text("t,point_err_deg\n0.0,1.0\n0.02,0.9\n")
    (run / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    (run / name).unlink()
    if kind == "a FIFO":
        os.mkfifo(run / name)  # nobody writes it: its open would wait for ever
    else:
        (run / name).symlink_to("/dev/zero")  # never ends
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(run), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    if name == "telemetry.csv":
        assert "neither a run directory" in proc.stderr  # a run is told by its telemetry being a file
    else:
        assert f"{run / name}: " in proc.stderr and "not" in proc.stderr
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


@pytest.mark.parametrize("pace", ["1e-300", "0.0005"])
def test_a_pace_slower_than_a_thousandth_of_real_time_is_refused(tmp_path, pace):
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--pace", pace, "--no-plots", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert proc.returncode == 2, proc.stderr
    assert "--pace: must be a factor of the wall clock of at least 0.001" in proc.stderr
    assert "Traceback" not in proc.stderr

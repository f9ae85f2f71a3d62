"""A session that finished every run, its ``finished`` record in campaign.json refused by the disk (the
record's temporary file cannot be made: a full disk, a directory in its place), left campaign.json saying
``running``; read back with no session holding the lock that is ``killed`` — and its own summary.json, and
every ``hil report`` after, said the finished campaign's last session was killed. The session now says how
it ended as it knows it, and a report reads a finished session's summary over the same runs as its word.

A real ``hil montecarlo`` process, its record refused at a drawn run, ``hil report`` as a subprocess."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import RUNS

ROOT = Path(__file__).resolve().parents[1]
RUNS_ASKED = 3


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(after_rows=st.integers(1, RUNS_ASKED - 1))
def test_a_finished_session_whose_end_record_the_disk_refused_is_not_said_killed(
    scenario, tmp_path_factory, after_rows
):
    out = tmp_path_factory.mktemp("refused") / "out"
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(RUNS_ASKED), "--seed", "5",
           "--workers", "1", "--batch", "1", "--out", str(out), "--no-plots"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120.0
        while _rows(out) < after_rows:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.01)
        (out / "campaign.json.tmp").mkdir()  # the record's rewrite refused from now on
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err[-2000:]
    assert "the session's end not recorded" in err  # said as it happened
    assert json.loads((out / "campaign.json").read_text())["session"]["state"] == "running"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ended"] == "finished" and "interrupted" not in summary, summary.get("ended")
    for flags in (["--no-plots"], []):
        done = subprocess.run(
            [sys.executable, "-m", "hil", "report", *flags, str(out)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, (done.stdout[-1500:], done.stderr[-1500:])
        assert "killed" not in done.stdout and "PARTIAL" not in done.stdout, done.stdout
    assert json.loads((out / "summary.json").read_text())["ended"] == "finished"

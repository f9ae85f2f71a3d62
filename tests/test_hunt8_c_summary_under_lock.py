"""A campaign directory's summary.json must never contradict its runs.csv, and two writers must never
meet in it.

- A session let go of the directory's lock, then wrote summary.json (and the plots): a second session
  taking the directory in between appended runs that summary never counted. Now the moment the lock is
  free the summary already describes every row of runs.csv.
- ``hil report DIR`` (drawing) beside a session still writing rewrote summary.json from the runs so far:
  killed afterwards, the session left that summary standing beside a longer runs.csv. Now it reports the
  runs so far and leaves summary.json and the plots to the session.
- A reader's question "is a session writing?" (``hil report``, ``hil gcs``: a shared lock held for
  microseconds) at the moment a session started refused the session, "another session is writing".

Real ``hil montecarlo`` / ``hil report`` subprocesses, a real reader process asking the lock."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.files.writing import writer_holds
from hil.montecarlo.store import RUNS, ResultStore, read_manifest, read_runs

ROOT = Path(__file__).resolve().parents[1]


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _campaign(scenario: Path, out: Path, runs: int, *extra: str) -> list[str]:
    return [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "5",
            "--workers", "1", "--batch", "1", "--out", str(out), *extra]  # fmt: skip


def _start(cmd: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )


def _wait_rows(proc: subprocess.Popen[str], out: Path, rows: int) -> None:
    deadline = time.monotonic() + 120.0
    while _rows(out) < rows:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.01)


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.mark.parametrize("plots", [False, True], ids=["no-plots", "plots"])
def test_the_summary_describes_runs_csv_the_moment_the_directory_is_free(scenario, tmp_path, plots):
    out = tmp_path / "out"
    proc = _start(_campaign(scenario, out, 2, *([] if plots else ["--no-plots"])))
    try:
        _wait_rows(proc, out, 1)  # the session holds the directory by now
        deadline = time.monotonic() + 120.0
        while writer_holds(out):  # the moment it is free, a second session may take it
            assert time.monotonic() < deadline
        freed_at = time.monotonic()
        summary_there = (out / "summary.json").is_file()
        rows = len(read_runs(out).index)
        summary = json.loads((out / "summary.json").read_text()) if summary_there else None
        proc.communicate(timeout=120)
    finally:
        _stop(proc)
    assert proc.returncode == 0
    assert summary is not None, (
        f"no summary.json when the lock was let go ({time.monotonic() - freed_at:.3f} s)"
    )
    assert summary["runs"] == rows == 2 and summary["ended"] == "finished"
    if plots:
        assert (out / "plots").is_dir()


def test_report_beside_a_session_leaves_its_summary_to_it(scenario, tmp_path):
    out = tmp_path / "out"
    proc = _start(_campaign(scenario, out, 30, "--no-plots"))
    try:
        _wait_rows(proc, out, 1)
        done = subprocess.run(
            [sys.executable, "-m", "hil", "report", str(out)], cwd=ROOT, capture_output=True, text=True,
            timeout=300,
        )  # fmt: skip
        written = (out / "summary.json").exists()
        still_running = proc.poll() is None
    finally:
        _stop(proc)  # killed: whatever summary stands must be the session's or none
    assert still_running, "the session ended before the report: the scenario runs too fast for this test"
    assert "Traceback" not in done.stderr, done.stderr
    assert "still running" in done.stdout and "a session is writing this campaign" in done.stdout, done.stdout
    assert done.returncode == 3, (done.returncode, done.stderr[-1500:])
    assert not written, "hil report wrote summary.json beside a session still writing runs.csv"


def test_a_session_starts_while_a_reader_keeps_asking_whether_one_writes(scenario, tmp_path):
    out = tmp_path / "out"
    made = subprocess.run(
        _campaign(scenario, out, 1, "--no-plots"), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert made.returncode == 0, made.stderr[-2000:]
    info = read_manifest(out)
    asker = subprocess.Popen(
        [sys.executable, "-c",
         "import sys\nfrom hil.files.writing import writer_holds\nwhile True: writer_holds(sys.argv[1])",
         str(out)],
        cwd=ROOT,
    )  # fmt: skip
    try:
        time.sleep(1.0)  # its imports done: asking
        assert asker.poll() is None
        for _ in range(200):  # a session's opening at 200 moments of the reader's questions
            with ResultStore(out, info) as store:
                assert store.finished == {0}
    finally:
        asker.kill()
        asker.wait()

"""``hil report RUN_DIR`` of a run that is still running (a hunt's finding), through the real commands: a
``hil run`` paced at the wall clock, reported while it writes. A run directory without summary.json was
always said ``no summary.json (the run was killed)``: a live run's rows so far read as the whole of a run
that had died. The run's writer holds its directory's lock until its summary.json is written
(:mod:`hil.files.writing`); the report now tells the two apart by it."""

from __future__ import annotations

import subprocess
import sys
import time

from hil.runtime.runlog import SUMMARY, TELEMETRY


def _hil(*argv: str, cwd) -> subprocess.CompletedProcess[str]:  # type: ignore[no-untyped-def]
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_a_run_still_running_is_reported_as_such_never_as_killed(tmp_path):
    out = tmp_path / "runs"
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hil",
            "run",
            "--pace",
            "1",
            "--duration",
            "30",
            "--no-plots",
            "--out",
            str(out),
        ],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        rows = 0
        while rows < 3 and time.monotonic() < deadline:  # its header and a few rows written
            time.sleep(0.2)
            tel = list(out.glob(f"*/{TELEMETRY}"))
            rows = len(tel[0].read_bytes().splitlines()) if tel else 0
        assert rows >= 3, run.stderr.read() if run.poll() is not None else "no rows in 120 s"
        run_dir = tel[0].parent
        assert not (run_dir / SUMMARY).exists()  # 30 s after the slew at the wall clock: still running
        done = _hil("report", "--no-plots", str(run_dir), cwd=tmp_path)
        assert done.returncode == 3, done.stderr  # its rows so far: not a whole run
        assert "not a whole run" in done.stderr, done.stderr
        assert "killed" not in done.stdout, done.stdout
        assert "still being written" in done.stdout, done.stdout
    finally:
        run.terminate()  # the run's own child: its SIGTERM ends it disarmed (hil run, status 1)
        run.communicate(timeout=120)
    done = _hil("report", "--no-plots", str(run_dir), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "still being written" not in done.stdout and "exit" in done.stdout, done.stdout

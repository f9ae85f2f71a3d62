"""A campaign extended (``--runs 8`` on one of 2) and interrupted with Ctrl-C after some of the new runs:
runs.csv holds them (honest), but the earlier session's summary.json still said 2 runs, 2 ok, and nothing on
disk said which was current. Now that summary is written again over the runs on disk, marked
``interrupted`` with the runs asked for; a campaign interrupted before any summary is left without one.
A real ``hil montecarlo`` process, a real SIGINT to its process group."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import RUNS, read_runs

ROOT = Path(__file__).resolve().parents[1]


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _campaign(scenario: Path, out: Path, runs: int) -> list[str]:
    return [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "5",
            "--workers", "1", "--batch", "1", "--out", str(out), "--no-plots"]  # fmt: skip


def _interrupt_after(cmd: list[str], out: Path, rows: int) -> tuple[int, str]:
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and _rows(out) < rows:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, err


def test_an_interrupted_extension_summarises_the_runs_on_disk_and_says_it_was_interrupted(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "out"
    first = subprocess.run(_campaign(scenario, out, 2), cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    assert json.loads((out / "summary.json").read_text())["runs"] == 2
    status, err = _interrupt_after(_campaign(scenario, out, 8), out, 4)
    assert status == 130, err
    on_disk = len(read_runs(out).index)
    assert 4 <= on_disk < 8
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == on_disk
    assert summary["interrupted"]["runs_asked"] == 8 and summary["interrupted"]["runs_on_disk"] == on_disk


def test_a_campaign_interrupted_before_its_first_summary_has_none(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "out"
    status, err = _interrupt_after(_campaign(scenario, out, 8), out, 2)
    assert status == 130, err
    assert not (out / "summary.json").exists()

"""``hil report`` on a campaign that is not whole printed ``PARTIAL`` and exited 0: a CI job or script that
gates on its exit status (``hil report mc/c1 && publish``) was told the figures of 3 runs of 40 were the
campaign's. It now exits 3 (documented in ``hil report --help``) for a partial campaign, keeps 0 for a
whole one, and 2 — a directory it could not report — wins over 3.

Real ``hil montecarlo`` processes, a real SIGINT to the process group, ``hil report`` as a subprocess."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import RUNS

ROOT = Path(__file__).resolve().parents[1]
ASKED = 40


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _campaign(scenario: Path, out: Path, runs: int) -> list[str]:
    return [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "5",
            "--workers", "1", "--batch", "1", "--out", str(out), "--no-plots"]  # fmt: skip


def _report(*dirs: Path, plots: bool = False) -> subprocess.CompletedProcess[str]:
    flags = [] if plots else ["--no-plots"]
    return subprocess.run(
        [sys.executable, "-m", "hil", "report", *flags, *map(str, dirs)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    """A whole campaign of 2 runs, and one of 40 asked interrupted (SIGINT) after its first rows."""
    base = tmp_path_factory.mktemp("campaigns")
    scenario = write_quick_scenario(base)
    whole, partial = base / "whole", base / "partial"
    done = subprocess.run(
        _campaign(scenario, whole, 2), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    proc = subprocess.Popen(
        _campaign(scenario, partial, ASKED),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and _rows(partial) < 1:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130
    assert 1 <= _rows(partial) < ASKED
    return whole, partial


@pytest.mark.parametrize("plots", [False, True], ids=["no-plots", "plots"])
def test_a_partial_campaign_exits_3_and_a_whole_one_0(dirs, plots):
    whole, partial = dirs
    done = _report(partial, plots=plots)
    assert "PARTIAL" in done.stdout, done.stdout
    assert done.returncode == 3, (done.returncode, done.stdout[-1500:], done.stderr[-1500:])
    assert f"{partial}: not a whole campaign" in done.stderr and "Traceback" not in done.stderr
    ok = _report(whole, plots=plots)
    assert ok.returncode == 0 and "PARTIAL" not in ok.stdout, ok.stdout + ok.stderr


def test_several_dirs_a_partial_one_is_3_and_one_not_reported_is_2(dirs, tmp_path):
    whole, partial = dirs
    assert _report(whole, partial).returncode == 3
    assert _report(partial, whole).returncode == 3
    missing = _report(whole, partial, tmp_path / "nothing-here")
    assert missing.returncode == 2, missing.stderr


def test_the_help_documents_the_status():
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0
    assert "exit status:" in done.stdout and "  3 " in done.stdout and "PARTIAL" in done.stdout

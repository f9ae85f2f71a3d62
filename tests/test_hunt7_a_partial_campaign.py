"""A campaign stopped before its first summary.json — Ctrl-C, SIGTERM, or the process killed — then
reported by ``hil report``: its runs.csv of 3 runs of 40 was summarised as a whole campaign of 3 runs, exit
0, since nothing on disk said how many runs were asked. campaign.json now records the session's runs asked
and how it ended (``killed`` told by the directory's lock), and the report says ``PARTIAL``: N of M. A
campaign.json written before that record still reads (runs asked unknown, said); one whose record was
edited into something no session writes is an error naming the file and the key.

Real ``hil montecarlo`` processes, real signals to their process group, ``hil report`` as a subprocess."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import RUNS, read_runs

ROOT = Path(__file__).resolve().parents[1]
ASKED = 40


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _campaign(scenario: Path, out: Path, runs: int) -> list[str]:
    return [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "5",
            "--workers", "1", "--batch", "1", "--out", str(out), "--no-plots"]  # fmt: skip


def _stop_after(cmd: list[str], out: Path, rows: int, signum: int) -> int:
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and _rows(out) < rows:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        os.killpg(proc.pid, signum)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode


def _report(out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "report", "--no-plots", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.mark.parametrize(
    ("signum", "rows", "ended"),
    [
        (signal.SIGINT, 1, "interrupted (SIGINT)"),
        (signal.SIGTERM, 3, "interrupted (SIGTERM)"),
        (signal.SIGKILL, 2, "killed"),
    ],  # fmt: skip
    ids=["sigint", "sigterm", "sigkill"],
)
def test_a_campaign_stopped_before_its_first_summary_is_reported_partial(
    scenario, tmp_path, signum, rows, ended
):
    out = tmp_path / "out"
    status = _stop_after(_campaign(scenario, out, ASKED), out, rows, signum)
    assert status in (130, 143, -signal.SIGKILL), status
    assert not (out / "summary.json").exists()
    on_disk = len(read_runs(out).index)
    assert rows <= on_disk < ASKED
    done = _report(out)
    assert done.returncode == 3, done.stderr[-2000:]  # a partial campaign: not whole
    assert f"interrupted: {on_disk} runs on disk of {ASKED} asked" in done.stdout, done.stdout
    assert f"its last session: {ended}" in done.stdout, done.stdout
    assert "PARTIAL" in done.stdout


def test_a_finished_campaign_is_not_said_partial_and_an_old_one_says_its_ask_is_unknown(scenario, tmp_path):
    out = tmp_path / "out"
    done = subprocess.run(_campaign(scenario, out, 2), cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs_asked"] == 2 and summary["ended"] == "finished" and "interrupted" not in summary
    assert "PARTIAL" not in done.stdout and "unknown" not in done.stdout
    report = _report(out)
    assert report.returncode == 0 and "PARTIAL" not in report.stdout, report.stdout + report.stderr
    # a campaign.json written before the session was recorded: read, its ask said unknown
    info = json.loads((out / "campaign.json").read_text())
    del info["session"]
    (out / "campaign.json").write_text(json.dumps(info))
    old = _report(out)
    assert old.returncode == 0, old.stderr[-2000:]
    assert re.search(r"runs asked\s+unknown", old.stdout), old.stdout
    # edited into what no session writes: an error naming the file and the key, no traceback
    for record in ([], {"runs_asked": "40", "state": "finished"}, {"runs_asked": 40, "state": "done"}):
        (out / "campaign.json").write_text(json.dumps({**info, "session": record}))
        bad = _report(out)
        assert bad.returncode == 2, bad.stdout + bad.stderr
        assert "campaign.json" in bad.stderr and "session" in bad.stderr and "Traceback" not in bad.stderr

"""A campaign extension stopped by an error — its Dask scheduler lost mid-campaign — left the earlier
session's summary.json as it was: "2 runs, 2 ok", no mark, beside a runs.csv of more, and ``hil report``
summarised the directory as a whole campaign. Ctrl-C's path already rewrote it marked ``interrupted``; an
error that ends a session once its runs have begun now does the same, with how it ended (``stopped: ...``),
and campaign.json's session record says it (a real ``dask scheduler`` killed under a real campaign)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from montecarlo_support import write_quick_scenario
from test_montecarlo_beside_lost_infrastructure import _Cluster

from hil.montecarlo.store import MANIFEST, RUNS, read_runs

ROOT = Path(__file__).resolve().parents[1]


def _cmd(scenario: Path, out: Path, runs: int, *extra: str) -> list[str]:
    return [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "5",
            "--batch", "1", "--out", str(out), "--no-plots", *extra]  # fmt: skip


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def test_an_extension_stopped_by_a_lost_scheduler_is_summarised_partial(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    first = subprocess.run(
        _cmd(scenario, out, 2, "--workers", "1"), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert first.returncode == 0, first.stderr[-2000:]
    cluster = _Cluster(tmp_path)
    proc = subprocess.Popen(
        _cmd(scenario, out, 12, "--scheduler", cluster.address),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120.0
        while _rows(out) < 4 and proc.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        cluster.kill_scheduler()
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        cluster.close()
    assert proc.returncode == 2, stderr
    assert "Traceback" not in stderr, stderr
    on_disk = len(read_runs(out).index)
    assert 4 <= on_disk < 12
    session = json.loads((out / MANIFEST).read_text())["session"]
    assert session["runs_asked"] == 12 and session["state"] == "stopped", session
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == on_disk, summary["runs"]  # not the earlier session's 2
    assert summary["interrupted"]["runs_asked"] == 12, summary["interrupted"]
    assert summary["interrupted"]["ended"].startswith("stopped: "), summary["interrupted"]
    report = subprocess.run(
        [sys.executable, "-m", "hil", "report", "--no-plots", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert report.returncode == 3, report.stderr[-2000:]  # a partial campaign: not whole
    assert f"interrupted: {on_disk} runs on disk of 12 asked (its last session: stopped: " in report.stdout

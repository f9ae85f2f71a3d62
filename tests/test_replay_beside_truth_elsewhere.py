"""A replay whose ground truth overlaps none of its estimates (the truth's clock another than the log's: a
motion-capture export not aligned, a truth file of another take) scores nothing, and says so.

It wrote ``"rmse_deg": {"total": NaN, ...}`` and ``"rate_rmse_rad_s": NaN`` into summary.json — Python's
``NaN``, not JSON: a strict reader (a browser's, jq, pandas' ``read_json``) refused the whole file — and
printed "RMSE nan / nan / nan deg over 0 samples" with no word of why. Now the figures not scored are null,
summary.json is strict JSON, and a warning (printed, and in the summary's ``warnings``) says that the truth
lies elsewhere, with both spans."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.estimation.sensors import SensorLog, Truth
from hil.logs import project_csv, read_log

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


def _refuse_constant(name: str) -> object:
    raise ValueError(f"{name} is not JSON")


@pytest.mark.parametrize("shift_s", [100.0, -50.0, 4.5])
def test_a_truth_beside_the_estimates_scores_nothing_and_says_so(tmp_path, shift_s):
    log = read_log(FIXTURE)
    assert log.truth is not None
    truth = Truth(log.truth.t + shift_s, log.truth.R)
    path = project_csv.write(SensorLog(log.streams, "elsewhere", "csv", truth), tmp_path / "elsewhere.csv")
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(path), "--out", str(out), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "RMSE nan" not in run.stdout and "RMS nan" not in run.stdout, run.stdout
    assert "overlaps none of the estimates" in run.stdout and "nothing scored" in run.stdout, run.stdout
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"), parse_constant=_refuse_constant)
    assert summary["rate_rmse_rad_s"] is None
    assert set(summary["rmse_deg"].values()) <= {None, 0}, summary["rmse_deg"]  # the count is 0
    assert any("overlaps none of the estimates" in w for w in summary["warnings"]), summary["warnings"]

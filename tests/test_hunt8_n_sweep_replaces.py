"""A sweep run again over an earlier bench CSV: it says what it will replace (a sweep starts over, it does
not resume), and one that measures no step at all leaves the earlier file as it was.

``hil calibrate sweep`` stopped before its first step (its guard tripped at once: a battery floor above
the pack) wrote a header-only file marked partial over a complete earlier sweep: the data was lost, and
the file left was one no fit can read ("no data rows after the header"), said as "0 steps -> path". The
command is the real one in a subprocess, its board the emulator (``emu://``), its files real.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hil.calibration.bench import read_bench_csv

BENCH = Path(__file__).resolve().parents[1] / "fixtures" / "calibration" / "bench"


def _sweep(out_dir: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "calibrate", "sweep", "--port", "emu://", "--unit", "0",
         "--out-dir", str(out_dir), *extra],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


@pytest.mark.parametrize("floor_v", ["59", "13"])  # far above the pack, and just above it (12.6 V)
def test_a_sweep_stopped_before_its_first_step_keeps_the_earlier_csv(tmp_path, floor_v):
    csv = tmp_path / "unit0_rotor.csv"
    shutil.copy(BENCH / "unit0_rotor.csv", csv)
    before = csv.read_bytes()
    run = _sweep(tmp_path, "--min-battery", floor_v)
    assert run.returncode == 1 and "stopped early: battery" in run.stderr, run.stderr
    assert csv.read_bytes() == before  # not emptied: the earlier sweep still fits
    assert len(read_bench_csv(csv)) == 204
    out = run.stdout
    assert f"unit 0: {csv} holds a complete sweep of 204 rows: this sweep starts over" in out, out
    assert f"unit 0: no step measured: no bench CSV written; {csv} is left as it was" in out, out
    assert "0 steps ->" not in out, out


def test_a_sweep_over_a_partial_csv_says_it_starts_over(tmp_path):
    csv = tmp_path / "unit0_gimbal_angle.csv"
    text = (BENCH / "unit0_gimbal_angle.csv").read_text().splitlines()
    csv.write_text(
        "\n".join(["# status: partial: stopped early: interrupted (SIGINT); 9 of 41 steps", *text[:13]])
        + "\n"
    )
    run = _sweep(tmp_path, "--map", "gimbal_angle", "--step", "100", "--directions", "up", "--settle", "0.1",
                 "--settle-window", "0.2", "--dwell", "0.1")  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert (
        "holds a partial sweep of 9 rows (stopped early: interrupted (SIGINT); 9 of 41 steps)" in run.stdout
    )
    assert "this sweep starts over (it does not resume)" in run.stdout
    assert read_bench_csv(csv).partial is None and len(read_bench_csv(csv)) == 11

"""A campaign's drawn phone is held to what the host admits, as a scenario file's is
(:func:`hil.scenario.reader.phone_out_of_range`): a gyroscope bias drawn to 50 rad/s had every gyroscope
reading of its run refused as out of range, and the run ended "lost" after a 15 s phone gap — in a
campaign with such a dispersion, every run, its row saying nothing of why. The run is now an error whose
row names the draw; draws within range run as before. Through the real ``hil montecarlo`` command."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest


def _campaign(tmp_path: Path, bias: str) -> list[dict[str, str]]:
    dispersions = tmp_path / "phone.toml"
    dispersions.write_text(f"[sensors.gyr]\nbias = {bias}\n", encoding="utf-8")
    out = tmp_path / "mc"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", "cubesat-1u", "--runs", "2", "--workers", "1",
         "--duration", "2", "--no-plots", "--dispersions", str(dispersions), "--out", str(out)],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode in (0, 1), done.stderr[-3000:]
    with open(out / "runs.csv", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("bias", ["50.0", '{ dist = "uniform", low = 45.0, high = 60.0 }'])
def test_a_drawn_phone_beyond_the_hosts_range_is_a_runs_error_naming_the_draw(tmp_path, bias):
    rows = _campaign(tmp_path, bias)
    assert len(rows) == 2
    for row in rows:
        said = " ".join(row.values())
        assert "sensors.gyr.bias" in said and "beyond" in said, row


def test_a_drawn_phone_within_range_runs(tmp_path):
    rows = _campaign(tmp_path, "0.01")
    assert len(rows) == 2
    assert all("beyond" not in " ".join(row.values()) for row in rows)

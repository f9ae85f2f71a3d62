"""Runs compared (hil/gcs/compare.py) without a browser: two real lockstep run directories through the
source, its stream and ``hil gcs A B``; what is not a comparison is refused with the reason."""

from __future__ import annotations

import json
import subprocess
import sys
import urllib.request

import pytest
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.gcs.compare import CompareSource
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry
from protocol.errors import InputFormatError


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("compare")
    a = run(quick_scenario(30.0), RunOptions(out_root=root / "a", duration_s=2.0, label="wide")).run_dir
    b = run(quick_scenario(15.0), RunOptions(out_root=root / "b", duration_s=2.0, label="narrow")).run_dir
    return a, b


def test_the_source_sends_the_first_run_then_the_others_as_overlays(two_runs):
    a, b = two_runs
    source = CompareSource([a, b], follow=False)
    first = source.poll()
    assert (
        first.info is not None and first.info["run"] == a.name and first.info["compare"] == [a.name, b.name]
    )
    assert first.overlays == [
        {"run": 1, "name": b.name, "columns": list(read_telemetry(b / "telemetry.csv").columns), "note": ""}
    ]
    rows_b = [row for k, rows in first.overlay_rows if k == 1 for row in rows]
    tel_b = read_telemetry(b / "telemetry.csv")
    assert len(rows_b) == tel_b.rows and rows_b[-1][0] == tel_b["t"][-1]
    assert len(first.rows) == read_telemetry(a / "telemetry.csv").rows
    assert not source.poll().overlays  # described once


def test_hil_gcs_compares_the_run_directories_it_is_given(two_runs, tmp_path):
    a, b = two_runs
    proc = subprocess.Popen([sys.executable, "-m", "hil", "gcs", str(a), str(b), "--gcs", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("ground station: http://127.0.0.1:"), line
        api = line.split(": ", 1)[1].strip().replace("/?token=", "/api/info?token=")

        def described() -> dict:  # {} until the station has read the first run
            with urllib.request.urlopen(api, timeout=10) as answer:
                return json.loads(answer.read())

        info = wait_for(described, 30, "the run's description")
        assert info["mode"] == "replay" and info["compare"] == [a.name, b.name]
    finally:
        proc.terminate()
        proc.wait(10)


def test_what_is_not_a_comparison_says_why(two_runs, tmp_path):
    a, _ = two_runs
    with pytest.raises(InputFormatError, match="at least two"):
        CompareSource([a])
    with pytest.raises(InputFormatError, match="given twice"):
        CompareSource([a, a.parent / ".." / a.parent.name / a.name])
    with pytest.raises(InputFormatError, match="not a directory"):
        GroundStation.compare([a, tmp_path / "nowhere"], bind="127.0.0.1:0")
    bad = subprocess.run([sys.executable, "-m", "hil", "gcs", str(a), str(a)], capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert bad.returncode == 2 and "given twice" in bad.stderr

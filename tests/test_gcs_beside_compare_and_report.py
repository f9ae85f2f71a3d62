"""Beside the compared runs' and ``hil report``'s paths: an overlay that cannot be drawn (its telemetry no
run's) or stops being followed (its directory replaced under the page), and a summary.json whose
``max_gimbal_rate_limit`` — the one value ``hil report``'s plots take from it — is not a number.

Before: the overlay's error was dropped by the comparison (the page's header named the run and its plots
simply lacked it; ``/api/stats`` said ``rows: 0`` and nothing else), and ``hil report`` died in a
TypeError's traceback after printing the summary. Through :class:`~hil.gcs.compare.CompareSource`, a
real station's ``/api/stats``, the page in chromium (marked ``browser``) and ``hil report`` as a process.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import request, wait_for
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.compare import CompareSource


def run_dir(d: Path, rows: int, header: str = "t,phase,point_err_deg", marker: int = 1) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    width = len(header.split(","))
    lines = "".join(",".join([str(k / 50), str(marker), *["1.5"] * (width - 2)]) + "\n" for k in range(rows))
    (d / "telemetry.csv").write_text(header + "\n" + lines)
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    return d


def overlay_states(batches: list) -> dict:
    told = [b.status["overlays"] for b in batches if b.status is not None and "overlays" in b.status]
    return told[-1] if told else {}


# --------------------------------------------------------------------------- compare
def test_an_overlay_whose_telemetry_is_no_run_s_is_said_in_the_status_and_the_stats(tmp_path):
    a = run_dir(tmp_path / "a", 10)
    b = run_dir(tmp_path / "b", 10, header="x,y,z")
    source = CompareSource([a, b], follow=False)
    batches = [source.poll() for _ in range(3)]
    assert not [o for batch in batches for o in batch.overlays] and not any(b.overlay_rows for b in batches)
    said = overlay_states(batches)["b"]
    assert said["state"] == "error" and "no 't' column first" in said["error"]
    assert batches[0].status["state"] == "read"  # the first run's own status still there
    assert source.counters()["b"]["state"] == "error" and "no 't'" in source.counters()["b"]["error"]


@settings(max_examples=10, deadline=None)
@given(rows_b=st.integers(1, 100), new_rows=st.integers(0, 300))
def test_an_overlay_replaced_under_the_page_stops_and_says_so(tmp_path_factory, rows_b, new_rows):
    root = tmp_path_factory.mktemp("cmp")
    a = run_dir(root / "a", 20)
    b = run_dir(root / "b", rows_b)
    source = CompareSource([a, b])
    first = source.poll()
    assert sum(len(rows) for _, rows in first.overlay_rows) == rows_b
    shutil.rmtree(b)
    run_dir(b, new_rows, marker=2)
    (b / "summary.json").write_text(json.dumps({"exit": "completed"}))
    batches = [source.poll() for _ in range(3)]
    assert not [r for batch in batches for _, rows in batch.overlay_rows for r in rows]
    said = overlay_states(batches)["b"]
    assert said["state"] == "read" and said["exit"] is None
    # the directory made anew may take its old inode number back, or not: what the station sees replaced
    # first — the directory or its telemetry.csv — is the file system's to decide; either is said
    assert "telemetry.csv was" in said["error"] or "run directory was removed or replaced" in said["error"]
    assert not source.sources[1].finished


def test_the_station_s_stats_name_the_overlay_that_cannot_be_drawn(tmp_path):
    a = run_dir(tmp_path / "a", 10)
    b = run_dir(tmp_path / "b", 10, header="x,y,z")
    with GroundStation.compare([a, b], bind="127.0.0.1:0", follow=False) as station:
        status, stats = request(station, "GET", f"/api/stats?token={station.token}", token=None)
    assert status == 200 and stats["compare"]["b"]["state"] == "error"
    assert "not a run's telemetry" in stats["compare"]["b"]["error"]


@pytest.fixture
def browser():
    yield from chromium()


def _note(driver) -> str:
    return str(js(driver, "return document.getElementById('note').textContent"))


@pytest.mark.browser
def test_the_page_says_why_an_overlay_is_not_drawn(browser, tmp_path):
    a = run_dir(tmp_path / "a", 30)
    b = run_dir(tmp_path / "b", 10, header="x,y,z")
    with GroundStation.compare([a, b], bind="127.0.0.1:0", follow=False) as station:
        browser.get(station.url)
        first = "return window.gcs.state.store && window.gcs.state.store.n"
        wait_for(lambda: js(browser, first) == 30, 30, "the first run's rows")
        wait_for(lambda: "b: " in _note(browser), 30, "the overlay's error in the note")
        assert "not a run's telemetry" in _note(browser)
    assert not page_errors(browser)


# ------------------------------------------------------------------ a run directory contradicting itself
@pytest.mark.parametrize("logged", [2, 3, 4, 6])
def test_a_scenario_toml_whose_units_are_not_the_telemetry_s_is_not_drawn(tmp_path, logged):
    """``scenario.toml`` (cubesat-1u: 4 units) copied into a run directory whose telemetry has ``logged``
    units: before, the page drew the scenario's 4 units and its limits over rows that hold another
    number; now the note says so and the units are the telemetry's, as without a scenario."""
    gimbals = ",".join(f"gimbal_angle_{i}" for i in range(logged))
    d = run_dir(tmp_path / "run", 10, header=f"t,phase,point_err_deg,{gimbals}")
    shutil.copy(Path(__file__).parents[1] / "fixtures/scenarios/cubesat-1u.toml", d / "scenario.toml")
    with GroundStation.replay(d, bind="127.0.0.1:0", follow=False) as station:
        status, info = request(station, "GET", f"/api/info?token={station.token}", token=None)
    assert status == 200 and info["n_units"] == logged
    if logged == 4:  # the run's own scenario: drawn
        assert info["scenario"] == "cubesat-1u" and len(info["units"]) == 4 and info["alarms"]
    else:
        assert "scenario.toml has 4 units, the telemetry" in info["note"]
        assert info["units"] == [] and info["alarms"] == [] and "scenario" not in info


# --------------------------------------------------------------------------- hil report
@pytest.mark.parametrize("limit", ['"fast"', "[1, 2]", '{"rad_s": 1}'])
def test_hil_report_says_a_summary_whose_rate_limit_is_not_a_number_is_damaged(tmp_path, limit):
    d = run_dir(tmp_path / "run", 40, header="t,phase,point_err_deg,gimbal_rate_0,gimbal_rate_1")
    summary = {"exit": "completed", "mode": "lockstep", "max_gimbal_rate_limit": None}
    text = json.dumps(summary).replace('"max_gimbal_rate_limit": null', f'"max_gimbal_rate_limit": {limit}')
    (d / "summary.json").write_text(text)
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(d)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert "summary.json damaged (max_gimbal_rate_limit is" in done.stdout and "Traceback" not in done.stderr

"""``hil report`` (and ``hil montecarlo``'s table) beside what a campaign's or a run's files hold — each
found by a hunt, each through the real command or the CLI's main function on real files:

1. a campaign run with ``--duration 30`` on a scenario of ``duration_s = 10`` was reported against the
   scenario text's 10 s (``settle_s <= 10``: 0 %, "10 s each"), and drawing, its summary.json was
   rewritten so, where ``hil montecarlo`` had printed 100 %;
2. a run directory whose run failed before its first row (a port that could not be opened) had figures it
   never measured printed as zeros (``failsafe events 0``), its limits as ``None``, its missing RMSE as "no
   ground truth"; drawing, it was an error ("no telemetry rows to plot", status 2) and every directory
   after it on the command line was never reported;
3. lines of runs.csv dropped (a run's row twice, a bad index) were counted in summary.json only; a status
   other than ok/failed was a failure with an empty error; an ok run with an empty metric left its
   figures unsaid while counted ok; a negative settle time or final error passed;
4. summary.json values of types no run writes (``true`` for a rate, a negative count, a number for
   ``exit``) were printed as figures (``1.000 rad/s``, ``-3``).
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from gcs_support import quick_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main
from hil.montecarlo import Campaign, parse_dispersions
from hil.montecarlo.campaign import summarise_dir
from hil.montecarlo.metrics import METRICS, TRACES, trace_length
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import MANIFEST, RUNS, ResultStore
from hil.montecarlo.summary import NO_ERROR, format_table
from hil.runtime import RunOptions, run
from hil.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'


def hil(*argv: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MPLCONFIGDIR": tempfile.gettempdir()}
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300, cwd=ROOT, env=env
    )


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """The quick scenario as its file says it: ``duration_s = 1.0``."""
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


def _campaign(
    out: Path, scenario, metrics: list[dict[str, float]], duration_s: float | None = None
) -> Campaign:
    """A campaign directory at ``out`` as a session writes it: one ok run per ``metrics`` (a metric left out
    is written empty), run ``duration_s`` long (``--duration``; None: the scenario's own)."""
    if duration_s is not None:
        scenario = scenario.with_changes(slew=replace(scenario.slew, duration_s=duration_s))
    campaign = Campaign(
        scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=len(metrics), seed=1
    )
    samples = trace_length(scenario.slew.duration_s, campaign.trace_hz)
    with ResultStore(out, campaign.manifest()) as store:
        for i, figures in enumerate(metrics):
            columns = {f"spacecraft.inertia_scale.{a}": 1.0 + i / 100 for a in "xyz"}
            trace = np.full((len(TRACES), samples), 0.1, dtype=np.float32)
            store.append(RunResult(i, True, columns, {m: figures.get(m, math.nan) for m in METRICS}, trace))
    return campaign


def _good(settle_s: float, final_error_deg: float = 0.1) -> dict[str, float]:
    """A run's metrics: within every requirement of the quick scenario but ``settle_s``'s, as given."""
    return {
        "settle_s": settle_s,
        "final_error_deg": final_error_deg,
        "peak_error_deg": 20.0,
        "peak_tracking_deg": 1.0,
        "peak_gimbal_rate": 0.1,
        "min_delta": 1.1,
        "estimator_rmse_deg": 0.5,
        "failsafe_events": 0.0,
    }


def _line(text: str, start: str) -> str:
    lines = [line for line in text.splitlines() if line.startswith(start)]
    assert len(lines) == 1, (start, text)
    return lines[0]


# --------------------------------------------------------------------------- 1. the campaign's duration
def test_a_campaign_run_with_duration_is_reported_against_that_duration(tmp_path, scenario):
    """The scenario file says 1 s; the campaign ran 3 s (``--duration 3``); both runs settled at 1.5 and
    2.5 s. ``hil report`` prints what ``hil montecarlo`` printed — settle 100 %, "3 s each" — and, drawing,
    leaves summary.json saying so (before: ``settle_s <= 1``, 0 %, written into summary.json)."""
    out = tmp_path / "mc"
    campaign = _campaign(out, scenario, [_good(1.5), _good(2.5)], duration_s=3.0)
    printed_by_montecarlo = format_table(summarise_dir(out, campaign.scenario, workers_lost=0, write=False))
    assert "(3 s each)" in printed_by_montecarlo
    done = hil("report", "--no-plots", str(out))
    assert done.returncode == 0, done.stderr[-2000:]
    assert printed_by_montecarlo in done.stdout, done.stdout
    settle = _line(done.stdout, "settle ")
    assert "settle_s <= 3 " in settle and "100.0%" in settle, settle
    drawn = hil("report", str(out))
    assert drawn.returncode == 0, drawn.stderr[-2000:]
    written = json.loads((out / "summary.json").read_text())
    assert written["duration_s"] == 3.0
    assert (
        written["requirements"]["settle"]["limit"] == 3.0 and written["requirements"]["settle"]["rate"] == 1.0
    )


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    duration=st.floats(1.5, 20.0),
    settles=st.lists(st.one_of(st.floats(0.0, 25.0), st.just(math.inf)), min_size=1, max_size=6),
)
def test_settle_is_judged_against_the_duration_campaign_json_holds(
    tmp_path_factory, scenario, duration, settles
):
    """Whatever the campaign's duration and the runs' settle times: the scenario rebuilt from the text
    campaign.json keeps (as ``hil report`` rebuilds it, ``duration_s = 1.0``) judges ``settle`` against
    the campaign's duration, run by run."""
    out = tmp_path_factory.mktemp("dur") / "mc"
    _campaign(out, scenario, [_good(s) for s in settles], duration_s=duration)
    info = json.loads((out / MANIFEST).read_text())
    rebuilt = parse_scenario(info["scenario_toml"], out / MANIFEST)
    assert rebuilt.slew.duration_s == 1.0  # the file's, not the campaign's
    summary = summarise_dir(out, rebuilt, write=False)
    assert summary["duration_s"] == info["duration_s"] == duration
    settle = summary["requirements"]["settle"]
    assert settle["limit"] == duration and settle["passed"] == sum(s <= duration for s in settles)


# --------------------------------------------------------------------------- 2. a run that had no row
@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Path:
    """A real short lockstep run's directory, its plots removed."""
    result = run(quick_scenario(), RunOptions(out_root=tmp_path_factory.mktemp("runs"), duration_s=3.0))
    shutil.rmtree(result.run_dir / "plots", ignore_errors=True)
    return result.run_dir


@pytest.fixture(scope="module")
def failed_run(tmp_path_factory) -> Path:
    """The directory ``hil run`` leaves when its port cannot be opened: no telemetry row, a short summary."""
    out = tmp_path_factory.mktemp("failed")
    done = hil("run", "--no-plots", "--port", "/dev/null", "--out", str(out))
    assert done.returncode == 2, done.stderr[-2000:]
    (made,) = out.iterdir()
    assert (made / "telemetry.csv").read_text().count("\n") == 1  # its header alone
    return made


def test_a_run_that_failed_before_its_first_row_shows_no_figure_it_never_measured(failed_run):
    done = hil("report", "--no-plots", str(failed_run))
    assert done.returncode == 0, done.stderr[-2000:]
    out = done.stdout
    assert "None" not in out, out
    assert _line(out, "failsafe events") == "failsafe events   -  resets -  re-arms -"
    assert _line(out, "link  ") == "link              lost -  reconnects -  stale -  phone gaps -"
    assert _line(out, "peak gimbal rate") == "peak gimbal rate  - (limit -)"
    assert _line(out, "estimator RMSE") == "estimator RMSE    - (not measured)"
    assert "(not reached)" in _line(out, "settle time")
    assert "no telemetry rows (the run ended before its first): no plots" in out


def test_every_directory_is_reported_and_the_status_says_one_could_not_be(failed_run, real_run, tmp_path):
    """``hil report FAILED NEITHER GOOD``: the failed run reported without plots, the directory that is
    neither a run nor a campaign an error naming it, the good run reported and drawn after both; status 2
    for the one not reported (before: the failed run's "no telemetry rows to plot" ended the command)."""
    good = shutil.copytree(real_run, tmp_path / "good")
    neither = tmp_path / "neither"
    neither.mkdir()
    done = hil("report", str(failed_run), str(neither), str(good))
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert f"hil report: error: {neither}: neither a run directory" in done.stderr
    assert "1 of 3 directories not reported" in done.stderr
    assert "no telemetry rows" not in done.stderr
    assert f"run {failed_run}: 0 telemetry rows" in done.stdout
    assert f"run {good}: " in done.stdout and "pointing_error:" in done.stdout
    assert (good / "plots" / "pointing_error.png").is_file()
    both = hil("report", str(failed_run), str(good))  # every directory reported: status 0
    assert both.returncode == 0, both.stderr[-2000:]


# --------------------------------------------------------------------------- 3. what the table left unsaid
def test_the_table_says_what_it_dropped_and_what_it_could_not_judge(tmp_path, scenario):
    """Five runs written by a session, then runs.csv edited: run 1 written again (a later row: the earlier
    one dropped), a row of index -5 (dropped), run 2's status ``maybe`` with no error, run 3's final error
    emptied, run 4's settle time and final error negative. The table says each."""
    out = tmp_path / "mc"
    _campaign(out, scenario, [_good(0.5) for _ in range(5)])
    path = out / RUNS
    rows = list(csv.reader(path.open(newline="")))
    header, body = rows[0], rows[1:]
    col = {name: header.index(name) for name in ("status", "error", "settle_s", "final_error_deg")}
    again = list(body[1])
    bad_index = ["-5", *body[0][1:]]
    body[2][col["status"]] = "maybe"
    body[3][col["final_error_deg"]] = ""
    body[4][col["settle_s"]] = "-1.0"
    body[4][col["final_error_deg"]] = "-0.2"
    with path.open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([header, *body, again, bad_index])
    done = hil("report", "--no-plots", str(out))
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout
    assert "5 runs, 4 ok, 1 failed" in text
    assert "dropped          2 line(s) of runs.csv" in text
    left_out = _line(text, "left out")
    assert "settle_s 1" in left_out and "final_error_deg 2" in left_out
    assert "1 ok not judged" in _line(text, "settle ") and "60.0%" in _line(text, "settle ")
    assert "2 ok not judged" in _line(text, "final_error ") and "40.0%" in _line(text, "final_error ")
    assert f"run 2: {NO_ERROR}" in text and f"failed runs (1; 1 with {NO_ERROR})" in text


_CELL = st.one_of(
    st.floats(-5.0, 5.0, allow_nan=False).map(repr),
    st.just(""),
    st.just("nan"),
    st.just("inf"),
    st.just("-inf"),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cells=st.lists(st.tuples(st.booleans(), _CELL, _CELL), min_size=1, max_size=8))
def test_every_ok_run_is_in_a_metrics_figures_or_counted_out_and_passes_only_on_a_value(
    tmp_path_factory, scenario, cells
):
    """Any ok/failed mix, any settle_s and final_error_deg cells (numbers of either sign, empty, NaN,
    infinities) in a real runs.csv: every ok run is in a metric's figures or in its ``left_out``; a run
    passes a requirement only on a value at least 0 and within the limit, and an ok run without one is
    counted ``not_judged``."""
    out = tmp_path_factory.mktemp("cells") / "mc"
    _campaign(out, scenario, [_good(0.5) for _ in cells])
    path = out / RUNS
    rows = list(csv.reader(path.open(newline="")))
    header, body = rows[0], rows[1:]
    for row, (ok, settle, final) in zip(body, cells, strict=True):
        row[header.index("status")] = "ok" if ok else "failed"
        row[header.index("error")] = "" if ok else "RuntimeError: drawn"
        row[header.index("settle_s")] = settle
        row[header.index("final_error_deg")] = final
    with path.open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([header, *body])
    summary = summarise_dir(out, scenario, write=False)
    oks = sum(ok for ok, _, _ in cells)
    for k, (req, metric) in enumerate((("settle", "settle_s"), ("final_error", "final_error_deg"))):
        limit = summary["requirements"][req]["limit"]
        values = [float(c[1 + k]) if c[1 + k] else math.nan for c in cells]
        readable = [ok and not math.isnan(v) and v >= 0 for (ok, _, _), v in zip(cells, values, strict=True)]
        stats = summary["metrics"][metric]
        assert stats["n"] == sum(readable) and stats["n"] + stats["left_out"] == oks
        assert summary["requirements"][req]["passed"] == sum(
            r and v <= limit for r, v in zip(readable, values, strict=True)
        )
        assert summary["requirements"][req]["not_judged"] == oks - sum(readable)
    text = format_table(summary)  # what hil montecarlo and hil report print
    assert ("left out" in text) == any(s["left_out"] for s in summary["metrics"].values())


# --------------------------------------------------------------------------- 4. values no run writes
_FIGURES = {  # key → the line it is printed on
    "exit": "exit ",
    "sim_s": "exit ",
    "wall_s": "exit ",
    "realtime_factor": "exit ",
    "settle_s": "settle time",
    "settle_requirement_deg": "settle time",
    "final_error_deg": "final error",
    "peak_gimbal_rate": "peak gimbal rate",
    "max_gimbal_rate_limit": "peak gimbal rate",
    "estimator_rmse_deg": "estimator RMSE",
}
_COUNTS = {
    "failsafe_events": "failsafe events",
    "board_resets": "failsafe events",
    "rearms": "failsafe events",
    "link_lost": "link ",
    "reconnects": "link ",
    "stale_episodes": "link ",
    "phone_gaps": "link ",
}
_ANY = st.one_of(
    st.booleans(),
    st.text(max_size=6),
    st.lists(st.integers(0, 3), max_size=2),
    st.dictionaries(st.sampled_from("ab"), st.integers(0, 3), max_size=1),
)
_NEGATIVE = st.one_of(st.integers(-(10**6), -1), st.floats(-1e9, -1e-9, allow_nan=False))


@pytest.fixture(scope="module")
def hostile_run(real_run, tmp_path_factory) -> Path:
    return shutil.copytree(real_run, tmp_path_factory.mktemp("hostile") / "run")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    data=st.data(),
    key=st.sampled_from(sorted({**_FIGURES, **_COUNTS})),
)
def test_a_value_no_run_writes_is_unreadable_never_a_figure(hostile_run, capsys, data, key):
    """A value of a type no run writes in any printed figure of a real run's summary.json: ``hil report``
    (the CLI's main function) shows it as unreadable on its line and names it on a last line, never as a
    figure (``true`` for a rate was 1.000 rad/s, ``-3`` failsafe events were -3)."""
    original = json.loads((hostile_run / "summary.json").read_text())
    if key == "exit":
        value = data.draw(st.one_of(st.integers(-(10**9), 10**9), st.floats(-1e9, 1e9), _ANY))
        if isinstance(value, str):
            value = [value]  # a text is an exit reason
    elif key == "max_gimbal_rate_limit":  # what is no number there is the figures' damage, said before
        value = data.draw(_NEGATIVE)
    elif key in _COUNTS:
        value = data.draw(st.one_of(_NEGATIVE, st.floats(0, 1e6), _ANY))
    else:
        value = data.draw(st.one_of(_NEGATIVE, _ANY))
    (hostile_run / "summary.json").write_text(json.dumps({**original, key: value}))
    try:
        capsys.readouterr()
        status = main(["report", "--no-plots", str(hostile_run)])
        printed = capsys.readouterr().out
    finally:
        (hostile_run / "summary.json").write_text(json.dumps(original))
    assert status == 2  # a damaged summary: said on stderr, the rest printed
    assert "unreadable" in _line(printed, {**_FIGURES, **_COUNTS}[key]), printed
    damaged = _line(printed, "summary.json damaged (values no run writes")
    assert f"{key} is " in damaged


def test_the_hunts_summary_of_values_no_run_writes(hostile_run):
    """The hunt's summary.json: each such value unreadable, the missing counts "-", through the command."""
    original = json.loads((hostile_run / "summary.json").read_text())
    hostile = {**original, "peak_gimbal_rate": True, "failsafe_events": -3, "board_resets": "many"}
    hostile.update(final_error_deg=-5.0, exit=5)
    del hostile["link_lost"], hostile["rearms"]
    (hostile_run / "summary.json").write_text(json.dumps(hostile))
    try:
        done = hil("report", "--no-plots", str(hostile_run))
    finally:
        (hostile_run / "summary.json").write_text(json.dumps(original))
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr[-2000:]
    out = done.stdout
    assert _line(out, "exit ").startswith("exit              unreadable  (")
    assert _line(out, "final error") == "final error       unreadable"
    assert _line(out, "peak gimbal rate").startswith("peak gimbal rate  unreadable (limit")
    assert _line(out, "failsafe events") == "failsafe events   unreadable  resets unreadable  re-arms -"
    assert _line(out, "link  ").startswith("link              lost -  reconnects 0")
    damaged = _line(out, "summary.json damaged")
    for said in ("exit is 5", "final_error_deg is -5.0", "peak_gimbal_rate is true", "failsafe_events is -3"):
        assert said in damaged, damaged

"""A run's summary.json with figures that are not finite numbers (a hunt's finding). The run's pointing
figures come from its trace (:class:`hil.runtime.telemetry.RunTrace`); a tick without an estimate — on
hardware the estimate is the only attitude, and a phone whose stream restarts (its app restarted, its clock
jumped) restarts the estimator, none until its next step — has no pointing error (NaN in the trace). A run
whose last tick was such a one wrote ``"final_error_deg": NaN`` (and ``peak_error_deg`` NaN when no tick
had one): not JSON to a strict reader, and ``hil report`` said the run's own summary was damaged and showed
none of it. Now a figure never measured is null, and summary.json is written as strict JSON whatever it is
given (a NaN or an infinity: null)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.runtime.runlog import SUMMARY, read_summary, write_summary
from hil.runtime.telemetry import RunTrace


def _strict(text: str) -> object:
    """JSON as a strict reader takes it: NaN and Infinity refused."""

    def refuse(name: str) -> object:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def _no_nan(doc: object) -> bool:
    if isinstance(doc, float):
        return math.isfinite(doc)
    items = doc.values() if isinstance(doc, dict) else doc if isinstance(doc, list) else ()
    return all(map(_no_nan, items))


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--duration", "1", "--no-plots", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    (run_dir,) = out.iterdir()
    return run_dir


errors = st.one_of(st.floats(0.0, 180.0), st.just(math.nan))


@settings(max_examples=200, deadline=None)
@given(point=st.lists(errors, min_size=1, max_size=40), last_nan=st.booleans())
def test_a_trace_s_figures_are_numbers_or_none_never_nan(point, last_nan):
    trace = RunTrace()
    if last_nan:
        point = [*point, math.nan]
    for i, p in enumerate(point):
        trace.append(0.02 * i, p, p, math.nan, 0.01, 1.0)
    figures = trace.figures(0.5, 1.5)
    assert _no_nan(figures), figures
    measured = [p for p in point if not math.isnan(p)]
    assert figures["final_error_deg"] == (None if math.isnan(point[-1]) else point[-1])
    assert figures["peak_error_deg"] == (max(measured) if measured else None)


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-(2**53), 2**53), st.floats(), st.text(max_size=5)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=5), inner, max_size=4)
    ),
    max_leaves=20,
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(st.text(max_size=8), json_values, max_size=6))
def test_summary_json_is_strict_json_with_every_non_finite_number_null(tmp_path, doc):
    write_summary(tmp_path, doc)
    back = _strict((tmp_path / SUMMARY).read_text(encoding="utf-8"))
    assert _no_nan(back)
    assert read_summary(tmp_path) == back


def test_hil_report_shows_a_run_whose_last_tick_had_no_estimate(real_run):
    summary = read_summary(real_run)
    assert summary is not None
    trace = RunTrace()
    for i, p in enumerate([40.0, 20.0, 0.3, math.nan]):  # the phone restarted at the last tick
        trace.append(0.02 * i, p, p, math.nan, 0.01, 1.0)
    summary.update(trace.figures(0.5, 1.5))
    write_summary(real_run, summary)
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", "--no-plots", str(real_run)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "damaged" not in done.stdout, done.stdout
    assert "final error       -" in done.stdout, done.stdout
    _strict((real_run / SUMMARY).read_text(encoding="utf-8"))

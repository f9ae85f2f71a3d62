"""A campaign's envelope figure says across how many runs it is drawn. It said "across N runs" of every
point of it, while a run that failed or was cut short ends its trace early (NaN past its end) and one that
failed before its slew has none: the envelope's later part was fewer runs' than it said."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.montecarlo.plots import _runs_traced
from hil.montecarlo.store import read_traces


@given(ends=st.lists(st.integers(-1, 30), min_size=1, max_size=12))
def test_the_runs_an_envelope_is_drawn_across_are_counted_by_where_their_traces_end(ends):
    """``ends``: each run's last traced sample (-1: none); 30 samples a trace."""
    runs = np.full((len(ends), 30), np.nan)
    for row, end in enumerate(ends):
        runs[row, : end + 1] = 1.0
    said = _runs_traced(runs)
    traced = sum(end >= 0 for end in ends)
    early = sum(0 <= end < 29 for end in ends)
    assert said.startswith(f"{len(ends)} runs")
    assert (f"{early} ended early: {traced - early} at the end" in said) == (early > 0)
    assert (f"{len(ends) - traced} with no trace" in said) == (traced < len(ends))
    assert said == f"{len(ends)} runs" or (early or traced < len(ends))


def test_a_campaign_of_whole_runs_is_said_across_all_of_them(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", "2", "--workers", "1"]
        + ["--no-plots", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    _, traces = read_traces(out)
    for k in range(traces.shape[1]):
        assert _runs_traced(np.asarray(traces[:, k, :], dtype=float)) == "2 runs"

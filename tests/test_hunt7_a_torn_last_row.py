"""runs.csv's last row torn — a campaign killed (or its machine crashed) in the middle of a row's write,
or ``hil report`` reading a live campaign between a row's pieces reaching the file.

A row is a run's commit record when its line break is written: a session resuming the directory cuts an
unterminated last line off and runs that run again. ``hil report`` (and every summary) read it as a row all
the same: cut inside its last cell, ``failsafe_events`` ``12.0`` read ``1``, a wrong number in the figures,
said nowhere. The unterminated last line is now dropped and counted (``dropped_lines``), as the store
treats it; every run read has the values it was written with.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main
from hil.montecarlo import Campaign, parse_dispersions, read_runs
from hil.montecarlo.metrics import METRICS, TRACES
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import RUNS, ResultStore
from hil.scenario import load_scenario

INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'
RUNS_WRITTEN = 3


def _result(index: int, value: float) -> RunResult:
    columns = {f"spacecraft.inertia_scale.{a}": 1.0 + index / 100 for a in "xyz"}
    metrics = {name: value + index for name in METRICS}
    return RunResult(index, True, columns, metrics, np.full((len(TRACES), 5), index, dtype=np.float32), "")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


def _campaign(out: Path, scenario, value: float) -> Path:
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario, "i.toml"), runs=RUNS_WRITTEN, seed=1)
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(RUNS_WRITTEN):
            store.append(_result(i, value))
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=st.floats(0.0, 1e6, allow_nan=False).map(lambda v: round(v, 3)), cut=st.integers(1, 40))
def test_a_torn_last_row_is_dropped_and_counted_never_read_wrong(scenario, tmp_path, value, cut):
    out = tmp_path / "mc"
    if out.exists():
        shutil.rmtree(out)
    _campaign(out, scenario, value)
    data = (out / RUNS).read_bytes()
    last_start = data.rindex(b"\n", 0, len(data) - 1) + 1
    cut = min(cut, len(data) - last_start)  # within the last row: its line break, then its cells
    (out / RUNS).write_bytes(data[: len(data) - cut])
    torn = cut < len(data) - last_start  # some of the last row is left
    results = read_runs(out)
    assert results.dropped == (1 if torn else 0)
    assert results.index.tolist() == list(range(RUNS_WRITTEN - 1))
    for name in METRICS:
        for k, index in enumerate(results.index.tolist()):
            assert math.isclose(results.values[name][k], value + index), (name, index)


def test_hil_report_says_the_torn_row(scenario, tmp_path, capsys):
    out = _campaign(tmp_path / "mc", scenario, 12.0)
    data = (out / RUNS).read_bytes()
    (out / RUNS).write_bytes(data[:-4])  # "...,14.0\n" -> "...,1"
    assert main(["report", "--no-plots", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{RUNS_WRITTEN - 1} runs" in printed and "dropped          1 line(s) of runs.csv" in printed, (
        printed
    )

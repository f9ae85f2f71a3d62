"""``hil report`` of a campaign whose runs.csv header was edited by hand (a hunt, through the real command
on real files written by the campaign's own store).

A header that is not campaign.json's columns — a metric renamed, a column named twice, one dropped, two
swapped — was read as it stood: the renamed metric was missing from every figure, its runs said "ok not
judged: no readable value" (``--no-plots``, exit 0), and drawing was a ``KeyError`` traceback from the
plots (exit 1). A session resuming the directory refuses such a header already (``ResultStore``); the
report now does too: an error naming runs.csv, line 1, and the first column that differs (exit 2).
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main
from hil.montecarlo import Campaign, parse_dispersions
from hil.montecarlo.metrics import METRICS, TRACES, trace_length
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import RUNS, ResultStore
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'
GOOD = {
    "settle_s": 0.5,
    "final_error_deg": 0.1,
    "peak_error_deg": 20.0,
    "peak_tracking_deg": 1.0,
    "peak_gimbal_rate": 0.1,
    "min_delta": 1.1,
    "estimator_rmse_deg": 0.5,
    "failsafe_events": 0.0,
}


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """A campaign directory of three ok runs, as a session's store writes it."""
    scenario = load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=3, seed=1)
    samples = trace_length(scenario.slew.duration_s, campaign.trace_hz)
    out = tmp_path_factory.mktemp("made") / "mc"
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(3):
            columns = {f"spacecraft.inertia_scale.{a}": 1.0 + i / 100 for a in "xyz"}
            trace = np.full((len(TRACES), samples), 0.1, dtype=np.float32)
            store.append(RunResult(i, True, columns, dict(GOOD), trace))
    return out


def _with_header(made: Path, where: Path, edit) -> Path:
    """A copy of ``made`` whose runs.csv header is ``edit(header)``; its rows as they were."""
    out = where / "mc"
    out.mkdir(parents=True)
    for name in os.listdir(made):
        if (made / name).is_file():
            (out / name).write_bytes((made / name).read_bytes())
    rows = list(csv.reader((made / RUNS).open(newline="")))
    with (out / RUNS).open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([edit(list(rows[0])), *rows[1:]])
    return out


def _rename(at: int, name: str):
    def edit(header: list[str]) -> list[str]:
        header[at] = name
        return header

    return edit


def _swap(a: int, b: int):
    def edit(header: list[str]) -> list[str]:
        header[a], header[b] = header[b], header[a]
        return header

    return edit


@st.composite
def header_edits(draw):
    """A header edit that leaves the fixed columns (index, status, error) as they were: a metric or a
    parameter renamed (to a drawn name, or to another column's), two columns swapped."""
    width = 3 + 3 + len(METRICS)  # the fixed columns, three parameters, the metrics
    at = draw(st.integers(3, width - 1))
    kind = draw(st.sampled_from(["rename", "twice", "swap"]))
    if kind == "rename":
        name = draw(st.text(st.characters(min_codepoint=33, max_codepoint=0x2FFF), min_size=1, max_size=12))
        return _rename(at, name)
    other = draw(st.integers(3, width - 1).filter(lambda k: k != at))
    return _rename(at, f"<{other}>") if kind == "twice" else _swap(at, other)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edit=header_edits())
def test_a_header_edited_by_hand_is_an_error_naming_runs_csv_line_1(made, capsys, edit):
    """Any header edit that changes it: ``hil report --no-plots`` exits 2 naming runs.csv:1 and the
    column, and prints no figures (it printed figures without the renamed metric, exit 0)."""
    with tempfile.TemporaryDirectory() as where:
        header = list(csv.reader((made / RUNS).open(newline="")))[0]

        def named(h: list[str]) -> list[str]:
            edited = edit(list(h))
            return [header[int(c[1:-1])] if c.startswith("<") and c.endswith(">") else c for c in edited]

        out = _with_header(made, Path(where), named)
        edited = list(csv.reader((out / RUNS).open(newline="")))[0]
        capsys.readouterr()
        status = main(["report", "--no-plots", str(out)])
        said = capsys.readouterr()
        if edited == header:  # a swap of two equal names, a rename to its own name: nothing changed
            assert status == 0, said.err
            return
        assert status == 2, said
        assert f"{out / RUNS}:1: its header is not the campaign's columns" in said.err
        assert "pass rate" not in said.out


def test_drawing_a_campaign_with_a_renamed_metric_is_an_error_not_a_traceback(made, tmp_path):
    """The real command, drawing: a renamed ``final_error_deg`` was a KeyError's traceback (exit 1)."""
    out = _with_header(made, tmp_path, _rename(3 + 3 + METRICS.index("final_error_deg"), "final_err"))
    env = {**os.environ, "MPLCONFIGDIR": tempfile.gettempdir()}
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out)],
        capture_output=True, text=True, timeout=300, cwd=ROOT, env=env,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    column = 3 + 3 + METRICS.index("final_error_deg") + 1
    assert f"column {column} is 'final_err', not 'final_error_deg'" in done.stderr
    assert not (out / "summary.json").exists() or "final_err" not in (out / "summary.json").read_text()


def test_the_unedited_campaign_is_reported(made, capsys):
    status = main(["report", "--no-plots", str(made)])
    out = capsys.readouterr().out
    assert status == 0 and "3 runs, 3 ok, 0 failed" in out

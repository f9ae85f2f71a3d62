"""A fault campaign's runs.csv whose invariant violation counts were edited to values no run writes (a
hunt; real fault runs, the campaign's own store, ``hil report`` on the files).

Before: ``inf`` in an ``inv.*`` cell was an ``OverflowError`` traceback from ``hil report`` (and from the
summary of a session resuming the directory); ``-3`` was subtracted from the other runs' violations
("-6 violations"); ``nan`` counted as none, and a cell of text turned the whole column to text, so that
every run's violations of that invariant read as 0 — a broken campaign summarised as clean. Now such a row
is dropped and counted (``dropped_lines``), as a row whose metric is no number is: the summary is the one
of the directory without that row.
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main
from hil.montecarlo import Campaign, parse_dispersions
from hil.montecarlo.campaign import summarise_dir
from hil.montecarlo.runner import VIOLATION_COLUMNS, run_chunk
from hil.montecarlo.store import RUNS, ResultStore
from hil.scenario import load_scenario

FAULTS = "[faults]\nstall = { count = 1, duration_s = 0.4 }\n"


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


@pytest.fixture(scope="module")
def made(tmp_path_factory, scenario) -> Path:
    """A fault campaign of two real runs (a board stall each), as a session's store writes it."""
    campaign = Campaign(scenario, parse_dispersions(FAULTS, scenario, "faults.toml"), runs=2, seed=3)
    results = run_chunk(scenario, [campaign.draw(i) for i in range(2)], campaign.trace_hz)
    out = tmp_path_factory.mktemp("made") / "mc"
    with ResultStore(out, campaign.manifest()) as store:
        for result in results:
            store.append(result)
    return out


def _rows(out: Path) -> list[list[str]]:
    return list(csv.reader((out / RUNS).open(newline="")))


def _write(out: Path, rows: list[list[str]]) -> None:
    with (out / RUNS).open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(rows)


def _copy(made: Path, where: Path) -> Path:
    out = where / "mc"
    shutil.copytree(made, out)
    return out


NOT_A_COUNT = st.sampled_from(
    ["inf", "-inf", "nan", "NaN", "-3", "-0", "1e300", "1.5", "2.0", "abc", " 1", "0x10", "99999999999", "١"]
)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(0, 1), column=st.sampled_from(VIOLATION_COLUMNS), cell=NOT_A_COUNT)
def test_a_violation_count_no_run_writes_drops_its_row_and_leaves_the_others_figures(
    made, scenario, tmp_path_factory, row, column, cell
):
    """A drawn row's drawn ``inv.*`` cell made a value no run writes: the summary is the directory's
    without that row (one line dropped, said), never a traceback nor the other run's violations hidden."""
    where = tmp_path_factory.mktemp("edited")
    edited, without = _copy(made, where / "a"), _copy(made, where / "b")
    rows = _rows(made)
    header, body = rows[0], rows[1:]
    damaged = [list(r) for r in body]
    damaged[row][header.index(column)] = cell
    _write(edited, [header, *damaged])
    _write(without, [header, *(r for k, r in enumerate(body) if k != row)])
    got = summarise_dir(edited, scenario, write=False)
    expected = summarise_dir(without, scenario, write=False)
    assert got["dropped_lines"] == 1
    assert got == {**expected, "dropped_lines": 1}


def test_hil_report_of_an_infinite_violation_count_is_no_traceback(made, tmp_path, capsys):
    """The command: ``inf`` in a run's ``inv.no_crash_or_hang`` was an OverflowError's traceback."""
    out = _copy(made, tmp_path)
    rows = _rows(out)
    rows[1][rows[0].index(VIOLATION_COLUMNS[0])] = "inf"
    _write(out, rows)
    capsys.readouterr()
    assert main(["report", "--no-plots", str(out)]) == 0
    said = capsys.readouterr().out
    assert "2 runs" not in said and "1 runs" in said
    assert "dropped          1 line(s) of runs.csv" in said

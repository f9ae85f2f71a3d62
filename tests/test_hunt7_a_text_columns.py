"""A fault campaign's runs.csv whose text columns were edited so that every cell reads as a number: the
``exit`` column written ``0``/``1`` (exit codes, by a script), ``faults.list`` or ``inv.first`` numbers.

Before: read_runs took such a column for numbers, and the summary read the exits (and the faults
injected, and the first violations) from the text columns only: ``exits`` came out empty — two runs said
nothing of how they ended — and ``faults injected`` nothing, though every row was read. The columns a run
writes as text are now read as text, whatever their cells; the summary's counts hold every run's cell as
it is written (real fault runs, the campaign's own store, ``hil report`` on the files).
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main
from hil.montecarlo import Campaign, parse_dispersions
from hil.montecarlo.campaign import summarise_dir
from hil.montecarlo.runner import run_chunk
from hil.montecarlo.store import RUNS, ResultStore
from hil.scenario import load_scenario

FAULTS = "[faults]\nstall = { count = 1, duration_s = 0.4 }\n"
NUMBERS = st.one_of(
    st.integers(-10, 10**6).map(str),
    st.sampled_from(["1e160", "-0.0", "0.5", "nan", "inf", "-inf", "007", "1_0"]),
)


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


def _edited(made: Path, where: Path, column: str, cells: list[str]) -> Path:
    out = where / "mc"
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(made, out)
    rows = list(csv.reader((out / RUNS).open(newline="")))
    j = rows[0].index(column)
    for row, cell in zip(rows[1:], cells, strict=True):
        row[j] = cell
    with (out / RUNS).open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(rows)
    return out


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(exits=st.lists(NUMBERS, min_size=2, max_size=2))
def test_exits_written_as_numbers_are_counted_as_written(made, scenario, tmp_path, exits):
    out = _edited(made, tmp_path, "exit", exits)
    summary = summarise_dir(out, scenario, write=False)
    assert summary["dropped_lines"] == 0
    expected: dict[str, int] = {}
    for cell in exits:
        expected[cell] = expected.get(cell, 0) + 1
    assert summary["exits"] == expected
    assert sum(summary["exits"].values()) == summary["runs"] == 2


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(column=st.sampled_from(["faults.list", "inv.first"]), cells=st.lists(NUMBERS, min_size=2, max_size=2))
def test_other_text_columns_written_as_numbers_are_read_as_written(made, scenario, tmp_path, column, cells):
    out = _edited(made, tmp_path, column, cells)
    summary = summarise_dir(out, scenario, write=False)
    if column == "faults.list":  # a fault written as a number is a fault of that "kind", counted
        assert sum(summary["faults_injected"].values()) == 2
    else:  # each run's first violation as written
        assert list(summary["first_violations"].values()) == cells


def test_hil_report_says_the_exits_of_an_exit_column_of_numbers(made, tmp_path, capsys):
    out = _edited(made, tmp_path, "exit", ["0", "1"])
    assert main(["report", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "exits            0 1, 1 1" in printed, printed
    assert json.loads((out / "summary.json").read_text())["exits"] == {"0": 1, "1": 1}

"""``hil report`` on a campaign directory whose files are damaged, each read through the real command.

* a summary.json nested 200 000 deep: ``_previous_workers_lost`` read it with ``json.loads`` (no bound):
  a RecursionError's traceback;
* a FIFO named summary.json: its open waited for a writer — ``hil report`` hung for ever;
* a ``detection.list`` / ``recovery.list`` cell that is not ``kind:seconds`` (``stall:abc``, no colon, an
  empty number): a ValueError's traceback, every figure of the campaign lost with it.

Now: the first is a damaged summary.json (its workers_lost taken as 0, said), the second a ConfigError naming
the file (status 2, at once), the third a dropped and counted cell (``dropped_times``)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.montecarlo import Campaign, parse_dispersions, read_runs
from hil.montecarlo.campaign import summarise_dir
from hil.montecarlo.metrics import METRICS, TRACES
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import RUNS, ResultStore
from hil.montecarlo.summary import fault_figures
from hil.scenario import load_scenario

INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


def _result(index: int) -> RunResult:
    columns = {f"spacecraft.inertia_scale.{a}": 1.0 + index / 100 for a in "xyz"}
    metrics = {name: float(index) for name in METRICS}
    return RunResult(index, True, columns, metrics, np.full((len(TRACES), 5), index, dtype=np.float32), "")


def _make(out: Path, scenario) -> Path:
    """A campaign directory of 2 runs at ``out``, as a session writes it (no summary.json yet)."""
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=2, seed=1)
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(2):
            store.append(_result(i))
    return out


@pytest.fixture
def made(tmp_path, scenario):
    return _make(tmp_path / "mc", scenario)


def _report(out: Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "report", "--no-plots", str(out)],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=Path(__file__).resolve().parents[1],
    )


def test_a_summary_json_nested_deeply_is_damaged_not_a_recursion_traceback(made):
    (made / "summary.json").write_text("[" * 200_000 + "]" * 200_000)
    done = _report(made)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "RecursionError" not in done.stderr
    assert "nested deeper" in done.stderr  # said: its workers_lost is not read from it
    assert "2 runs, 2 ok" in done.stdout
    drawn = subprocess.run(  # drawing, summary.json is written again, its workers_lost taken as 0
        [sys.executable, "-m", "hil", "report", str(made)], capture_output=True, text=True, timeout=120
    )
    assert drawn.returncode == 0, drawn.stderr[-2000:]
    assert json.loads((made / "summary.json").read_text())["workers_lost"] == 0


def test_a_fifo_named_summary_json_is_refused_at_once_naming_it(made):
    os.mkfifo(made / "summary.json")
    done = _report(made, timeout=30.0)  # before: a hang, until this timeout
    assert done.returncode == 2, done.stderr[-2000:]
    assert "summary.json" in done.stderr and "not a regular file" in done.stderr
    assert "Traceback" not in done.stderr


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(workers_lost=st.one_of(st.integers(-(10**30), 10**30), st.booleans(), st.text(max_size=3), st.none()))
def test_workers_lost_is_kept_only_when_it_is_a_count(tmp_path_factory, scenario, workers_lost):
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=1, seed=1)
    out = tmp_path_factory.mktemp("wl") / "mc"
    with ResultStore(out, campaign.manifest()) as store:
        store.append(_result(0))
    (out / "summary.json").write_text(json.dumps({"workers_lost": workers_lost}))
    kept = workers_lost if isinstance(workers_lost, int) and not isinstance(workers_lost, bool) else 0
    assert summarise_dir(out, scenario)["workers_lost"] == max(kept, 0)


# --------------------------------------------------------------------------- detection / recovery cells
_GOOD = st.builds(
    lambda kind, s: f"{kind}:{s:.4f}",
    st.sampled_from(["stall", "hang", "brownout", "unplug"]),
    st.floats(0.0, 100.0),
)
_BAD = st.one_of(
    st.sampled_from(
        ["stall:abc", "stall", "stall:", ":1.5", "1.5", "stall:nan", "stall:inf", "stall:-1", "all:1"]
    ),
    st.text(alphabet="abc:;.-1", min_size=1, max_size=8).filter(lambda t: ":" not in t or t.endswith(":")),
)


def _with_faults(out: Path, cells: list[tuple[str, str]]) -> None:
    """Add a fault campaign's ``faults.n``, ``detection.list`` and ``recovery.list`` columns to runs.csv."""
    path = out / RUNS
    rows = list(csv.reader(path.open(newline="")))
    rows[0] += ["faults.n", "detection.list", "recovery.list"]
    for row, (detection, recovery) in zip(rows[1:], cells, strict=True):
        row += ["1", detection, recovery]
    with path.open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(rows)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    cells=st.lists(
        st.tuples(
            st.lists(st.one_of(_GOOD, _BAD), max_size=3).map(";".join),
            st.lists(st.one_of(_GOOD, _BAD), max_size=3).map(";".join),
        ),
        min_size=2,
        max_size=2,
    )
)
@example(cells=[("1.5", ""), ("", "stall:1.0")])  # a column of numbers: read_runs takes it for a metric
def test_a_detection_or_recovery_cell_that_is_not_kind_seconds_is_dropped_and_counted(
    tmp_path_factory, scenario, cells
):
    """Any mix of good and bad items in runs.csv (a real file, read as ``hil report`` reads it): every
    cell with a bad item is dropped whole and counted, every good cell's times are in the figures."""
    made = _make(tmp_path_factory.mktemp("cells") / "mc", scenario)
    _with_faults(made, cells)
    figures = fault_figures(read_runs(made))

    def bad(cell: str) -> bool:
        return bool(_bad_items(cell))

    flat = [cell for pair in cells for cell in pair]
    assert figures["dropped_times"] == sum(1 for cell in flat if bad(cell))
    good = [item for cell in flat if not bad(cell) for item in filter(None, cell.split(";"))]
    n = figures["detection_s"].get("all", {}).get("n", 0) + figures["recovery_s"].get("all", {}).get("n", 0)
    assert n == len(good)


def _bad_items(cell: str) -> list[str]:
    """The items of ``cell`` that are not ``kind:seconds`` with a finite, non-negative number of seconds."""
    out = []
    for item in filter(None, cell.split(";")):
        kind, colon, text = item.rpartition(":")
        try:
            seconds = float(text)
        except ValueError:
            out.append(item)
            continue
        finite = seconds == seconds and abs(seconds) != float("inf")
        if not colon or not kind or kind == "all" or not finite or seconds < 0:
            out.append(item)
    return out


def test_hil_report_prints_the_campaign_with_a_bad_detection_cell(made, scenario):
    _with_faults(made, [("stall:abc", "stall:1.0"), ("stall:0.5", "unplug:")])
    done = _report(made)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert "2 runs, 2 ok" in done.stdout and "2 detection/recovery cells (dropped)" in done.stdout
    assert not (made / "summary.json").exists()  # --no-plots writes nothing
    summary = summarise_dir(made, scenario, write=False)
    assert summary["dropped_times"] == 2
    assert summary["detection_s"]["all"]["n"] == 1 and summary["recovery_s"]["all"]["n"] == 1

"""``hil report`` (and ``hil run``'s figures, :func:`hil.plots.run.plot_run`) on a real run's directory, and
on a campaign's, whose files or outputs are hostile — each found by a review, each through the real entry:

1. a campaign's report rewrote its summary.json (``--no-plots`` too), losing its ``interrupted`` record; a
   read-only campaign printed only "cannot write …/summary.json";
2. a time gap in the telemetry was drawn as a straight line of live-looking data;
3. a figure was written through a symbolic link planted at its path (``plots/delta.png -> victim``);
4. a column named twice in the header plotted only its last one, silently;
5. an event at ``"t": true`` was drawn at 1 s;
6. events.jsonl was held whole (1.7 GB for 195 MB) and 7. runs.csv too (2.1 GB for 196 MB);
8. no cap on the lines of a figure (20 000 markers, 20 000 ``gimbal_angle_N`` columns: minutes, GBs);
9. a summary.json starting with a BOM crashed the figures (report's own reader took it);
10. a command whose origin or id is a list, or a slew target that is not three numbers, crashed the markers;
11. values near the largest float (a battery at -1.7e308, a rate limit of -1e308) crashed matplotlib;
12. a ``plots`` that cannot be written was an OSError's traceback.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from gcs_support import quick_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from measure_support import traced_peak
from montecarlo_support import write_quick_scenario

from hil.montecarlo import Campaign, parse_dispersions, read_runs
from hil.montecarlo.metrics import METRICS, TRACES
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import RUNS, ResultStore
from hil.plots import markers as markers_module
from hil.plots.markers import FAULT, MAX_PER_KIND, run_markers
from hil.plots.run import plot_run
from hil.plots.streamed import MinMaxStream
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry
from hil.scenario import load_scenario
from protocol.errors import InputFormatError
from protocol.messages import MAX_UNITS

ROOT = Path(__file__).resolve().parents[1]
MB = 1 << 20


def hil(*argv: str, user: int | None = None) -> subprocess.CompletedProcess[str]:
    prefix = [] if user is None else ["setpriv", f"--reuid={user}", f"--regid={user}", "--clear-groups"]
    env = {**os.environ, "MPLCONFIGDIR": tempfile.gettempdir()}
    return subprocess.run(
        [*prefix, sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300, cwd=ROOT,
        env=env,
    )  # fmt: skip


@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Path:
    """A real short lockstep run's directory (telemetry, events, summary), its plots removed."""
    result = run(quick_scenario(), RunOptions(out_root=tmp_path_factory.mktemp("runs"), duration_s=3.0))
    shutil.rmtree(result.run_dir / "plots", ignore_errors=True)
    return result.run_dir


def copy_run(real_run: Path, to: Path) -> Path:
    shutil.copytree(real_run, to)
    return to


def _table(d: Path) -> tuple[list[str], list[list[str]]]:
    lines = (d / "telemetry.csv").read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def _write_table(d: Path, header: list[str], rows: list[list[str]]) -> None:
    (d / "telemetry.csv").write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")


# --------------------------------------------------------------------------- 1. a campaign's summary.json
INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'


def _result(index: int) -> RunResult:
    columns = {f"spacecraft.inertia_scale.{a}": 1.0 + index / 100 for a in "xyz"}
    metrics = {name: float(index) for name in METRICS}
    return RunResult(index, True, columns, metrics, np.full((len(TRACES), 5), index, dtype=np.float32), "")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


def _campaign(out: Path, scenario, runs: int = 3) -> Path:
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=runs, seed=1)
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(runs):
            store.append(_result(i))
    return out


INTERRUPTED = {
    "runs_asked": 8,
    "runs_on_disk": 3,
    "plots": "not drawn for these runs: hil report DIR draws them",
}


def test_report_no_plots_leaves_the_campaign_summary_and_its_interrupted_record(tmp_path, scenario):
    out = _campaign(tmp_path / "mc", scenario)
    written = json.dumps({"runs": 3, "workers_lost": 2, "interrupted": INTERRUPTED}, indent=2)
    (out / "summary.json").write_text(written)
    done = hil("report", "--no-plots", str(out))
    assert done.returncode == 3, done.stderr[-2000:]  # a partial campaign: not whole
    assert (out / "summary.json").read_text() == written  # not rewritten
    assert "interrupted: 3 runs on disk of 8 asked" in done.stdout
    drawn = hil("report", str(out))  # drawing: the summary written again, its record carried over
    assert drawn.returncode == 3, drawn.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["workers_lost"] == 2
    assert summary["interrupted"]["runs_asked"] == 8 and summary["interrupted"]["runs_on_disk"] == 3
    assert "hil report" in summary["interrupted"]["plots"]


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root to drop to 65534"
)
def test_report_no_plots_prints_a_read_only_campaign(scenario):
    top = Path(tempfile.mkdtemp(prefix="hil-ro-"))
    try:
        out = _campaign(top / "mc", scenario)
        (out / "summary.json").write_text(json.dumps({"workers_lost": 0}))
        for p in (top, out, *out.iterdir()):
            p.chmod(0o755 if p.is_dir() else 0o644)  # readable by all, writable by its owner (root) only
        done = hil("report", "--no-plots", str(out), user=65534)
        assert done.returncode == 0, done.stderr[-2000:]
        assert "3 runs, 3 ok" in done.stdout and "cannot write" not in done.stderr
    finally:
        shutil.rmtree(top)


# --------------------------------------------------------------------------- 2. a time gap
def test_report_counts_a_time_gap_and_the_figures_break_there(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "gap")
    header, rows = _table(d)
    cut = len(rows) // 3
    _write_table(d, header, rows[:cut] + rows[2 * cut :])  # a stall: a third of the run without a row
    done = hil("report", "--no-plots", str(d))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "1 time gaps" in done.stdout
    whole = hil("report", "--no-plots", str(real_run))
    assert "time gaps" not in whole.stdout  # a run that did not stall has none


@settings(max_examples=60, deadline=None)
@given(
    rows=st.integers(40, 6000),
    gaps=st.lists(st.tuples(st.floats(0.25, 0.95), st.floats(20.0, 1000.0)), max_size=4),
    block=st.integers(1, 3000),
    max_points=st.sampled_from([40, 2000]),
)
def test_a_gap_in_the_rows_is_a_break_in_every_drawn_series(rows, gaps, block, max_points):
    """Rows at 5 ms with drawn gaps (a stall of 20..1000 steps, after the first rows), fed in drawn blocks,
    thinned or not: each gap has a NaN between its two sides in the series drawn, and nowhere else."""
    dt = np.full(rows, 0.005)
    where = sorted({int(at * (rows - 1)) + 1 for at, _ in gaps})
    for at, (_, steps) in zip(where, gaps, strict=False):
        dt[at] = 0.005 * steps
    t = np.cumsum(dt)
    y = np.sin(t)[:, None]
    stream = MinMaxStream(1, max_points=max_points)
    for k in range(0, rows, block):
        stream.add(t[k : k + block], y[k : k + block])
    ts, ys = stream.series(0)
    assert stream.gaps.count == len(where)
    assert int(np.isnan(ys).sum()) == len(where)
    for at in where:
        before, after = t[at - 1], t[at]
        inside = (ts > before) & (ts < after)
        assert np.isnan(ys[inside]).sum() == 1  # the line is broken in the gap, once


# --------------------------------------------------------------------------- 3. links in plots/
def test_a_link_planted_in_plots_is_replaced_not_written_through(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "run")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (d / "plots").mkdir()
    (d / "plots" / "delta.png").symlink_to(victim)
    done = hil("report", str(d))
    assert done.returncode == 0, done.stderr[-2000:]
    assert victim.read_text() == "precious"
    png = d / "plots" / "delta.png"
    assert not png.is_symlink() and png.read_bytes().startswith(b"\x89PNG")
    assert not [p for p in (d / "plots").iterdir() if p.name.startswith(".")]  # no temporary left


def test_a_link_planted_in_a_campaigns_plots_is_replaced(tmp_path, scenario):
    out = _campaign(tmp_path / "mc", scenario)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / "plots").mkdir()
    (out / "plots" / "histograms.png").symlink_to(victim)
    done = hil("report", str(out))
    assert done.returncode == 0, done.stderr[-2000:]
    assert victim.read_text() == "precious" and not (out / "plots" / "histograms.png").is_symlink()


# --------------------------------------------------------------------------- 4. a column named twice
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_column_named_twice_is_refused_naming_line_1_and_the_column(real_run, tmp_path_factory, data):
    d = tmp_path_factory.mktemp("dup")
    header = (real_run / "telemetry.csv").read_text().splitlines()[0].split(",")
    original = data.draw(st.integers(1, len(header) - 1))
    twice = data.draw(st.integers(1, len(header) - 1).filter(lambda k: k != original))
    header[twice] = header[original]
    (d / "telemetry.csv").write_text(",".join(header) + "\n" + ",".join(["0.0"] * len(header)) + "\n")
    with pytest.raises(InputFormatError) as caught:
        read_telemetry(d / "telemetry.csv")
    assert caught.value.line == 1 and repr(header[original]) in str(caught.value)


def test_report_refuses_a_telemetry_with_a_column_named_twice(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "dup")
    header, rows = _table(d)
    header[header.index("delta")] = "point_err_deg"
    _write_table(d, header, rows)
    done = hil("report", str(d))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "telemetry.csv:1" in done.stderr and "'point_err_deg' named twice" in done.stderr


# --------------------------------------------------------------------------- 5, 10. hostile events
NOT_A_TIME = st.one_of(st.booleans(), st.sampled_from([math.nan, math.inf, -math.inf]), st.text(max_size=3))
NOT_A_KEY = st.one_of(
    st.booleans(),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=2), st.integers()),
    st.floats(allow_nan=True),
)
NOT_THREE_NUMBERS = st.one_of(
    st.lists(
        st.one_of(st.none(), st.text(max_size=2), st.booleans(), st.just(math.nan)), min_size=3, max_size=3
    ),
    st.lists(st.floats(), min_size=3, max_size=3).filter(lambda v: not all(map(math.isfinite, v))),
)


@settings(max_examples=100, deadline=None)
@given(t=NOT_A_TIME, kind=st.sampled_from(["board_reset", "slew_start", "link_lost", "command"]))
def test_an_event_whose_time_is_no_number_is_no_marker(t, kind):
    event = {"t": t, "kind": kind, "origin": "gcs", "id": 1, "command": "disarm"}
    assert run_markers([event]) == []


@settings(max_examples=100, deadline=None)
@given(origin=st.one_of(NOT_A_KEY, st.just("gcs")), ident=NOT_A_KEY, euler=NOT_THREE_NUMBERS)
def test_a_command_whose_origin_or_id_is_no_key_is_skipped_and_counted(origin, ident, euler):
    bad = {"t": 1.0, "kind": "command", "origin": origin, "id": ident, "command": "slew"}
    good = {
        "t": 2.0,
        "kind": "command",
        "origin": "gcs",
        "id": 7,
        "command": "slew",
        "target_euler_deg": euler,
    }
    marked = run_markers([bad, good])
    assert marked.malformed == 1
    assert [m.label for m in marked] == ["slew (gcs)"]  # no Euler label from what is not three numbers


def test_report_draws_a_run_with_hostile_command_events(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "ev")
    hostile = [
        {"t": True, "kind": "board_reset"},
        {"t": 1.0, "kind": "command", "origin": ["a"], "id": 1, "command": "hold"},
        {"t": 1.0, "kind": "command", "origin": "gcs", "id": {"x": 1}, "command": "hold"},
        {
            "t": 1.0,
            "kind": "command",
            "origin": "gcs",
            "id": 2,
            "command": "slew",
            "target_euler_deg": ["a", "b", "c"],
        },
        {
            "t": 1.5,
            "kind": "command",
            "origin": "gcs",
            "id": 3,
            "command": "slew",
            "target_euler_deg": [None, 1, 2],
        },
    ]
    with (d / "events.jsonl").open("a") as f:
        f.writelines(json.dumps(e) + "\n" for e in hostile)
    done = hil("report", str(d))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "pointing_error:" in done.stdout


# --------------------------------------------------------------------------- 6, 8. events streamed, capped
def test_the_figures_hold_the_markers_not_the_events(real_run, tmp_path):
    """~100 000 events (15 MB), 20 000 of them faults: plot_run's traced peak grows by less than the
    events' own size (held whole, each a dict, it grew by several times it), and each kind is capped."""
    small = copy_run(real_run, tmp_path / "small")
    big = copy_run(real_run, tmp_path / "big")
    with (big / "events.jsonl").open("a") as f:
        for k in range(100_000):
            kind = "board_reset" if k % 5 == 0 else "phone_other"
            f.write(
                json.dumps({"t": 0.5 + k * 1e-5, "kind": kind, "sender": "127.0.0.1:5000" + "x" * 80}) + "\n"
            )
    size = (big / "events.jsonl").stat().st_size
    _, base = traced_peak(lambda: plot_run(small))
    drawn, peak = traced_peak(lambda: plot_run(big))
    assert "pointing_error" in drawn
    assert peak - base < size, (peak - base, size)  # held whole: +281 MB for these 15 MB
    marked = run_markers(json.loads(line) for line in (big / "events.jsonl").read_text().splitlines())
    assert sum(m.kind == FAULT for m in marked) == MAX_PER_KIND
    assert marked.more[FAULT] >= 20_000 - MAX_PER_KIND


def test_units_beyond_a_boards_are_not_drawn_and_said(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "wide")
    header, rows = _table(d)
    extra = [f"gimbal_angle_{k}" for k in range(MAX_UNITS, MAX_UNITS + 2000)]
    _write_table(d, header + extra, [r + ["0.1"] * len(extra) for r in rows])
    done = hil("report", str(d))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "2000 per-unit columns of a unit no board has" in done.stdout


def test_markers_drawn_are_capped_per_kind():
    from matplotlib.figure import Figure

    ax = Figure().add_subplot()
    ax.set_xlim(0, 100)
    marks = run_markers({"t": k / 100, "kind": "link_lost"} for k in range(5000))
    drawn = markers_module.draw_markers(ax, marks)
    assert drawn == MAX_PER_KIND == len(ax.lines)
    assert any("not drawn" in label for label in ax.get_legend_handles_labels()[1])


# --------------------------------------------------------------------------- 7. runs.csv streamed
def test_read_runs_holds_numbers_not_the_files_text(tmp_path, scenario):
    """A runs.csv of ~20 MB: read_runs's traced peak stays near the numbers it returns (a float per cell),
    never the text and every row's cells (which took ~11 times the file)."""
    out = _campaign(tmp_path / "mc", scenario, runs=1)
    header = (out / RUNS).read_text().splitlines()[0]
    width = len(header.split(","))
    with (out / RUNS).open("a") as f:
        for i in range(1, 60_000):
            f.write(f"{i},ok,," + ",".join(repr(1.0 + i / 7 + j) for j in range(width - 3)) + "\n")
    size = (out / RUNS).stat().st_size
    results, peak = traced_peak(lambda: read_runs(out))
    assert len(results) == 60_000
    assert peak < 1.5 * size, (peak, size)


CELL = st.one_of(
    st.just(""),
    st.floats(allow_nan=False).map(repr),
    st.integers(-5, 5).map(str),
    st.text("ab:;", max_size=4),
)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_read_runs_reads_as_the_whole_file_read_did(tmp_path_factory, scenario, data):
    """Drawn rows (repeated indices, failed runs, a parameter column that turns to text) read streamed
    give what reading the whole file gives (a model of the former reader)."""
    out = _campaign(tmp_path_factory.mktemp("rr") / "mc", scenario, runs=1)
    header = (out / RUNS).read_text().splitlines()[0].split(",")
    rows = data.draw(
        st.lists(
            st.tuples(st.integers(0, 6), st.sampled_from(["ok", "failed"]), st.text("xy ", max_size=3), CELL),
            max_size=12,
        )
    )
    metrics = ["1.5"] * (len(header) - 4)
    with (out / RUNS).open("a", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        for index, status, error, cell in rows:
            w.writerow([index, status, error, cell, *metrics])
    got = read_runs(out)
    table: dict[int, list[str]] = {}
    for r in csv.reader(io.StringIO((out / RUNS).read_text())):
        if r and r[0] != "index":
            table[int(r[0])] = r
    order = sorted(table)
    assert got.index.tolist() == order
    assert got.ok.tolist() == [table[i][1] == "ok" for i in order]
    assert got.errors == {i: table[i][2] for i in order if table[i][1] != "ok"}
    assert got.dropped == len(rows) + 1 - len(order)
    cells = [table[i][3] for i in order]
    name = header[3]
    try:
        expected = [float(c) if c else math.nan for c in cells]
    except ValueError:
        # a number before the column's first text is its text again as repr gives it: equal as numbers
        assert [_norm(str(c)) for c in got.text[name]] == [_norm(c) for c in cells]
    else:
        np.testing.assert_array_equal(got.values[name], np.array(expected))


def _norm(c: str) -> str | float:
    try:
        return float(c) if c else c
    except ValueError:
        return c


# --------------------------------------------------------------------------- 9, 11. summary and values
def test_a_summary_json_with_a_bom_is_read_by_the_figures_too(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "bom")
    (d / "summary.json").write_bytes(b"\xef\xbb\xbf" + (d / "summary.json").read_bytes())
    done = hil("report", str(d))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "gimbal_rates:" in done.stdout
    assert "gimbal_rates" in plot_run(d)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    huge=st.floats(1.01e300, 1.7976931348623157e308),
    limit=st.one_of(st.floats(-1.8e308, 0.0), st.floats(1.01e300, 1.8e308), st.just(math.nan), st.booleans()),
)
def test_values_near_the_largest_float_are_gaps_said_not_a_crash(real_run, tmp_path_factory, huge, limit):
    d = copy_run(real_run, tmp_path_factory.mktemp("huge") / "run")
    header, rows = _table(d)
    battery, rate = header.index("battery_v"), header.index("gimbal_rate_0")
    for k, r in enumerate(rows):
        r[battery] = repr(-huge)
        r[rate] = repr(huge if k % 2 else -huge) if k % 3 == 0 else r[rate]
    _write_table(d, header, rows)
    summary = json.loads((d / "summary.json").read_text())
    summary["max_gimbal_rate_limit"] = limit
    (d / "summary.json").write_text(json.dumps(summary))
    drawn = plot_run(d)
    assert {"battery", "gimbal_rates"} <= set(drawn)


def test_report_draws_a_run_with_a_battery_at_minus_the_largest_float(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "neg")
    header, rows = _table(d)
    battery = header.index("battery_v")
    for r in rows:
        r[battery] = "-1.7e308"
    _write_table(d, header, rows)
    summary = json.loads((d / "summary.json").read_text())
    summary["max_gimbal_rate_limit"] = -1e308
    (d / "summary.json").write_text(json.dumps(summary))
    done = hil("report", str(d))
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr[-2000:]
    assert "battery:" in done.stdout


# --------------------------------------------------------------------------- 12. plots not writable
def test_a_plots_that_is_a_file_is_an_error_naming_it(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "run")
    (d / "plots").write_text("not a directory")
    done = hil("report", str(d))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert f"{d / 'plots'}" in done.stderr


def test_a_figure_whose_path_is_a_directory_is_an_error_naming_it(real_run, tmp_path):
    d = copy_run(real_run, tmp_path / "run")
    (d / "plots" / "delta.png").mkdir(parents=True)
    done = hil("report", str(d))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert f"cannot write {d / 'plots' / 'delta.png'}" in done.stderr


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root to drop to 65534"
)
def test_a_read_only_run_directory_is_an_error_naming_it(real_run):
    top = Path(tempfile.mkdtemp(prefix="hil-ro-"))
    try:
        d = copy_run(real_run, top / "run")
        for p in (top, d, *d.iterdir()):
            p.chmod(0o755 if p.is_dir() else 0o644)
        done = hil("report", str(d), user=65534)
        assert done.returncode == 2, done.stderr[-2000:]
        assert "Traceback" not in done.stderr and f"{d / 'plots'}" in done.stderr
    finally:
        shutil.rmtree(top)


@pytest.mark.parametrize("settled", ['"false"', '"no"', "[]", '{"x": 1}', "1", "0.0"])
def test_a_settle_verdict_that_is_not_true_or_false_is_damage_never_met(real_run, tmp_path, settled):
    """``settled`` other than true, false or null (a summary.json hil did not write) is named as damage:
    the report printed ``(met)`` for any non-empty string, list or object (truthiness)."""
    run = copy_run(real_run, tmp_path / "run")
    summary = json.loads((run / "summary.json").read_text())
    text = json.dumps({**summary, "settle_s": None}).replace('"settled": false', '"settled": true')
    text = text.replace('"settled": true', f'"settled": {settled}')
    (run / "summary.json").write_text(text)
    done = hil("report", str(run), "--no-plots")
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert "(met)" not in done.stdout, done.stdout
    assert "summary.json damaged" in done.stdout and "settled is" in done.stdout, done.stdout

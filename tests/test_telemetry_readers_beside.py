"""Beside the readers of a run's telemetry (``read_telemetry`` — ``hil report`` and the plots — and ``hil
gcs``'s run-directory source): a last line torn by a kill whose cells still parse, stray rows at large but
possible times spliced into a real run, and a long run read by ``hil report``.

Before: a torn last line whose cell count fitted was read as a row (``0.21234`` cut to ``0.2``: a wrong
value, silently); one row at t = 5e6 s (under the 1e7 s bound) put every later row "before" it, so the rest
of the run was dropped by every reader; ``hil report`` held every column of the telemetry as floats (and
its plots all of them again), ~1 GB for an hour at 200 Hz. Through real files of a real ``hil run``, the
readers, and ``hil report`` as a process.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from measure_support import MB, traced_peak

from hil.gcs.rundir import RunDirSource
from hil.runtime.runlog import read_telemetry


@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Path:
    """A real run's directory (``hil run``, lockstep, 5 s after the slew)."""
    out = tmp_path_factory.mktemp("runs")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--no-plots", "--duration", "5", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    (run,) = [d for d in out.iterdir() if d.is_dir()]
    return run


def _lines(run: Path) -> tuple[bytes, list[bytes]]:
    """The header and the rows of a run's telemetry, each with its line break."""
    header, *rows = (run / "telemetry.csv").read_bytes().splitlines(keepends=True)
    return header, rows


def _gcs_rows(d: Path) -> tuple[list[list], int]:
    """The rows ``hil gcs`` draws of a run directory read to its end, and the lines it counts as bad."""
    source = RunDirSource(d, follow=False)
    rows: list[list] = []
    for _ in range(1000):
        batch = source.poll()
        rows += batch.rows
        if source._done:  # type: ignore[attr-defined]
            return rows, source.bad_rows
    raise AssertionError("the run directory never read to its end")


# --------------------------------------------------------------------------- a torn last line
@pytest.mark.parametrize("keep", [0.3, 0.6, 0.97])
def test_a_last_line_torn_by_a_kill_is_dropped_by_every_reader_even_when_it_parses(tmp_path, real_run, keep):
    header, rows = _lines(real_run)
    last = rows[-1].rstrip(b"\r\n")
    cut = last[: int(len(last) * keep)]
    cells = cut.count(b",") + 1
    # torn inside a cell, the cells filled up to the header's count: a row that parses, with wrong values
    torn = cut + b"," * (header.count(b",") + 1 - cells)
    d = tmp_path / "run"
    d.mkdir()
    (d / "telemetry.csv").write_bytes(header + b"".join(rows[:-1]) + torn)
    tel = read_telemetry(d / "telemetry.csv")
    assert tel.rows == len(rows) - 1 and tel.dropped_lines == 1
    assert tel["t"][-1] == float(rows[-2].split(b",")[0])
    drawn, bad = _gcs_rows(d)
    assert len(drawn) == len(rows) - 1 and bad == 1


def test_a_last_line_with_its_line_break_is_a_row(tmp_path):
    path = tmp_path / "telemetry.csv"
    path.write_text("t,x\n0.0,1.0\n0.02,0.21234\n")
    tel = read_telemetry(path)
    assert tel.rows == 2 and tel.dropped_lines == 0 and tel["x"][-1] == 0.21234
    path.write_text("t,x\n0.0,1.0\n0.02,0.2")  # the same, killed while it was written
    tel = read_telemetry(path)
    assert tel.rows == 1 and tel.dropped_lines == 1 and tel["x"].tolist() == [1.0]


# --------------------------------------------------------------------------- stray rows spliced in
def _time(line: bytes) -> float:
    cell = line.split(b",", 1)[0]
    return float(cell) if cell else math.nan


INVALID = st.sampled_from(["1e300", "-1e300", "1e8", "-1e8", "nan", "inf", "-inf", ""])
FAR = st.floats(100.0, 9.9e6).flatmap(lambda x: st.sampled_from([x, -x]))  # possible, far off the run


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    strays=st.lists(
        st.tuples(st.floats(0.0, 1.0), st.one_of(INVALID, FAR.map(repr)), st.integers(1, 8)),
        min_size=1,
        max_size=4,  # at most 32 together: the look-ahead's rows
    )
)
def test_stray_rows_spliced_into_a_real_run_are_dropped_and_every_row_of_the_run_kept(
    tmp_path_factory, real_run, strays
):
    """Rows at times far off the run (possible ones too: 5e6 s is under the 1e7 s bound), spliced in
    anywhere, alone or several together: every row of the run is kept, in order, by ``read_telemetry``
    and by ``hil gcs`` alike, and each line not kept is counted. A stray row after the run's last is in
    order: taken (nothing tells it from a run that went on)."""
    header, rows = _lines(real_run)
    good = [float(r.split(b",", 1)[0]) for r in rows]
    lines = [(r, True) for r in rows]
    for where, t, count in strays:
        at = int(where * len(lines))
        rest = rows[at % len(rows)].split(b",", 1)[1]
        lines[at:at] = [(t.encode() + b"," + rest, False)] * count
    d = tmp_path_factory.mktemp("spliced")
    (d / "telemetry.csv").write_bytes(header + b"".join(r for r, _ in lines))
    last_good = max(i for i, (_, ok) in enumerate(lines) if ok)
    for kept, dropped in [
        ((tel := read_telemetry(d / "telemetry.csv"))["t"].tolist(), tel.dropped_lines),
        (lambda drawn_bad: ([r[0] for r in drawn_bad[0]], drawn_bad[1]))(_gcs_rows(d)),
    ]:
        assert kept[: len(good)] == good, "a row of the run dropped"
        extra = kept[len(good) :]
        tail = [_time(r) for r, _ in lines[last_good + 1 :]]
        assert all(math.isfinite(t) and good[-1] <= t <= 1e7 for t in extra) and extra == sorted(extra)
        assert set(extra) <= set(tail), "a stray row taken before the run's last row"
        assert len(kept) + dropped == len(lines)


def test_one_stray_row_at_5e6_s_drops_itself_not_the_rest_of_the_run(tmp_path, real_run):
    header, rows = _lines(real_run)
    at = len(rows) // 3
    stray = b"5000000.0," + rows[at].split(b",", 1)[1]
    (tmp_path / "telemetry.csv").write_bytes(header + b"".join(rows[:at]) + stray + b"".join(rows[at:]))
    tel = read_telemetry(tmp_path / "telemetry.csv")
    assert tel.rows == len(rows) and tel.dropped_lines == 1 and tel["t"][-1] < 100
    drawn, bad = _gcs_rows(tmp_path)
    assert len(drawn) == len(rows) and bad == 1


def test_a_real_jump_ahead_is_taken_and_what_follows_it_too():
    """A run that stalls (its clock jumps 30 s) and goes on: nothing dropped, the rows come out in order
    (the jump's row late, once the rows after it have said it is real)."""
    from hil.runtime.runlog import RowOrder

    order: RowOrder[float] = RowOrder()
    times = [k * 0.02 for k in range(100)] + [32.0 + k * 0.02 for k in range(100)]
    out = [r for t in times for r in order.offer(t, t)] + order.end()
    assert out == times and order.dropped == 0
    assert order.held == 0


def test_a_stray_row_is_held_no_longer_than_the_look_ahead():
    from hil.runtime.runlog import LOOKAHEAD_ROWS, RowOrder

    order: RowOrder[float] = RowOrder()
    out: list[float] = []
    for k in range(50):
        out += order.offer(k * 0.02, k)
    out += order.offer(5e6, -1)  # a stray: held
    held = []
    for k in range(50, 50 + LOOKAHEAD_ROWS):
        held += order.offer(k * 0.02, k)
        assert order.held <= LOOKAHEAD_ROWS + 1
    assert held == list(range(50, 50 + LOOKAHEAD_ROWS)) and order.dropped == 1  # judged: the run goes on
    assert order.offer(82 * 0.02, 82) == [82]  # nothing held: the next row comes out at once


# --------------------------------------------------------------------------- hil report of a long run
def _long_run(real_run: Path, d: Path, rows: int) -> Path:
    """``real_run``'s rows repeated with their times shifted on: ``rows`` rows at 200 Hz."""
    header, lines = _lines(real_run)
    d.mkdir()
    for name in ("events.jsonl", "summary.json", "scenario.toml"):
        (d / name).write_bytes((real_run / name).read_bytes())
    rests = [r.split(b",", 1)[1] for r in lines]
    with (d / "telemetry.csv").open("wb") as f:
        f.write(header)
        for start in range(0, rows, 10_000):
            f.write(
                b"".join(
                    b"%r,%s" % (0.1 + k * 0.005, rests[k % len(rests)]) for k in range(start, start + 10_000)
                )
            )
    return d


def test_hil_report_counts_a_long_run_s_rows_without_holding_its_columns(tmp_path, real_run):
    """``hil report --no-plots`` of 100 000 rows of 66 columns (50 MB as floats): it counts them, and holds
    (traced) a few MB, not the columns."""
    from hil.cli import main

    d = _long_run(real_run, tmp_path / "long", 100_000)
    assert main(["report", "--no-plots", str(real_run)]) == 0  # the modules it imports: not traced
    peaks = []
    for run in (real_run, d):
        status, peak = traced_peak(lambda run=run: main(["report", "--no-plots", str(run)]))
        assert status == 0
        peaks.append(peak)
    more = peaks[1] - peaks[0]  # than for the real run's ~400 rows (its parser, its summary: ~16 MB)
    assert more < 4 * MB, f"{more / MB:.0f} MB more traced for 100 000 rows"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", "--no-plots", str(d)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0 and "100000 telemetry rows" in done.stdout, done.stderr


def test_the_plots_read_only_the_columns_they_draw(tmp_path, real_run):
    """A run's figures from 20 000 rows that carry 400 columns no figure draws (64 MB as floats): the
    plots read the ones they draw, thinned as they come (hil.plots.streamed), and hold their points."""
    from hil.plots.run import plot_run

    header, lines = _lines(real_run)
    d = tmp_path / "wide"
    d.mkdir()
    extra = ",".join(f"x{i}" for i in range(400)).encode()
    ones = b",1.5" * 400
    with (d / "telemetry.csv").open("wb") as f:
        f.write(header.rstrip(b"\r\n") + b"," + extra + b"\r\n")
        for k in range(20_000):
            rest = lines[k % len(lines)].split(b",", 1)[1].rstrip(b"\r\n")
            f.write(b"%r,%s%s\r\n" % (0.1 + k * 0.005, rest, ones))
    drawn, peak = traced_peak(lambda: plot_run(d))
    assert "gimbal_rates" in drawn and drawn["gimbal_rates"].is_file()
    assert peak < 20 * MB, f"{peak / MB:.0f} MB traced"  # ~8 MB: a block of rows read, and the figures


# --------------------------------------------------------------------------- the plots' streamed envelope
@settings(max_examples=100, deadline=None)
@given(
    n=st.integers(0, 9000),
    block=st.integers(1, 700),
    max_points=st.sampled_from([4, 10, 2000]),
    seed=st.integers(0, 2**32 - 1),
    gaps=st.floats(0.0, 1.0),
)
def test_a_series_thinned_as_it_is_read_keeps_its_extremes_in_order_and_bounded(
    n, block, max_points, seed, gaps
):
    """Whatever the blocks the rows come in: at most ``max_points`` points a column, each a real row, in
    time order, with the column's lowest and highest values among them; all rows while there are no more;
    a column of NaN only is a gap (no number)."""
    import numpy as np

    from hil.plots.streamed import MinMaxStream

    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.005
    y = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-3, 4)
    y[rng.random((n, 3)) < gaps] = np.nan
    y[:, 2] = np.nan
    stream = MinMaxStream(3, max_points=max_points)
    for a in range(0, n, block):
        stream.add(t[a : a + block], y[a : a + block])
    assert stream.rows == n
    for c in range(3):
        ts, ys = stream.series(c)
        assert len(ts) <= max(max_points, 1) and np.all(np.diff(ts) > 0)
        rows = np.round(ts / 0.005).astype(int)
        np.testing.assert_array_equal(t[rows], ts)
        np.testing.assert_array_equal(y[rows, c], ys)
        if n <= max_points:
            assert len(ts) == n
        finite = np.isfinite(y[:, c])
        assert stream.finite[c] == finite.any()
        if finite.any():
            assert np.nanmax(ys) == y[finite, c].max() and np.nanmin(ys) == y[finite, c].min()
            assert stream.peak()[c] == np.abs(y[finite, c]).max()


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(
        st.one_of(st.floats(0.0, 0.05), st.floats(0.05, 1e4), st.just(0.0)), min_size=0, max_size=300
    ),
    start=st.floats(-1e6, 1e6),
)
def test_rows_in_time_order_all_come_out_whatever_their_steps(steps, start):
    """A run's own rows, in order — steady, uneven, stalled, repeated times, starting anywhere — are all
    taken, in order, none left held: the look-ahead only delays a jump, never drops a run's row."""
    from hil.runtime.runlog import MAX_ROW_TIME_S, RowOrder

    times = [start]
    for step in steps:
        times.append(times[-1] + step)
    times = [t for t in times if abs(t) <= MAX_ROW_TIME_S]
    order: RowOrder[int] = RowOrder()
    out = [r for i, t in enumerate(times) for r in order.offer(t, i)] + order.end()
    assert out == list(range(len(times))) and order.dropped == 0 and order.held == 0

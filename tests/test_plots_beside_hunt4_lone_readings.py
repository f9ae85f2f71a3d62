"""A measured value a run's figure drew as nothing (found beside the tested path of ``hil report``).

A line is drawn between two points only. A reading alone between gaps — the one row a board sent between
two silences (its other rows carry no board value), a run of a single row — and a burst of rows a long gap
away (a file spliced 10⁶ s later: a line shorter than a pixel) drew an empty figure, with the column's
legend: the run measured a value and its figure showed no data. Each such reading is now a dot
(:func:`hil.plots.series.lone_points`), in the run's figures and a replay's.
"""

from __future__ import annotations

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
from matplotlib.image import imread

from hil.plots.run import plot_run
from hil.runtime import RunOptions, run

ROOT = Path(__file__).resolve().parents[1]
LINE_RGB = np.array([0x1F, 0x77, 0xB4]) / 255  # matplotlib's first line colour (tab:blue)
AXES_INSIDE = (slice(44, 383), slice(92, 810))  # rows, columns of a run figure's axes (10 × 4 in at 110 dpi)


@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Path:
    """A real short lockstep run's directory, its plots and events removed (no marker drawn in blue)."""
    result = run(quick_scenario(), RunOptions(out_root=tmp_path_factory.mktemp("runs"), duration_s=3.0))
    shutil.rmtree(result.run_dir / "plots", ignore_errors=True)
    (result.run_dir / "events.jsonl").write_text("")
    return result.run_dir


def _battery_only(run_dir: Path, to: Path, keep: set[int], shift: dict[int, float] | None = None) -> Path:
    """A copy of ``run_dir`` whose telemetry has the time and ``battery_v`` only, the voltage blank (the board
    silent) on every row but those in ``keep``; rows in ``shift`` moved that many seconds later."""
    shutil.copytree(run_dir, to)
    lines = (run_dir / "telemetry.csv").read_text().splitlines()
    header = lines[0].split(",")
    t_at, v_at = header.index("t"), header.index("battery_v")
    out = ["t,battery_v"]
    for i, line in enumerate(lines[1:]):
        cells = line.split(",")
        t = float(cells[t_at]) + (shift or {}).get(i, 0.0)
        out.append(f"{t!r},{cells[v_at] if i in keep else ''}")
    (to / "telemetry.csv").write_text("\n".join(out) + "\n")
    return to


def _of_the_line(image: np.ndarray) -> np.ndarray:
    """Which pixels of ``image`` (H, W, 3) are the first line's colour over the white axes, whole or
    anti-aliased: a flat line half a pixel off the grid is drawn as two rows of its colour blended about
    half with white, neither of them the colour itself. Each channel then says the same blend."""
    blend = (1.0 - image) / (1.0 - LINE_RGB)  # 1: the colour itself, 0: white
    return (np.ptp(blend, axis=-1) < 0.12) & (blend.mean(axis=-1) > 0.3)


def _line_pixels(png: Path) -> int:
    """Pixels of the first line's colour inside the figure's axes (the legend is outside them)."""
    return int(np.sum(_of_the_line(imread(png)[AXES_INSIDE][..., :3])))


def _rows(run_dir: Path) -> int:
    return len((run_dir / "telemetry.csv").read_text().splitlines()) - 1


def test_report_draws_the_one_reading_a_board_sent_between_silences(real_run, tmp_path):
    """``hil report`` on a run whose board sent its battery voltage once: the figure shows it."""
    d = _battery_only(real_run, tmp_path / "once", keep={_rows(real_run) // 2})
    env = {**os.environ, "MPLCONFIGDIR": tempfile.gettempdir()}
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(d)], capture_output=True, text=True, timeout=300,
        cwd=ROOT, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert _line_pixels(d / "plots" / "battery.png") > 0


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_every_reading_kept_is_seen_in_its_figure(real_run, tmp_path, data):
    """Readings at drawn rows, alone or a few together, the rest of the run silent, and the rows after a
    drawn one spliced a drawn time later (up to 10⁶ s): every figure drawn shows each stretch of
    readings — the line's colour near each reading's time column."""
    rows = _rows(real_run)
    starts = data.draw(
        st.lists(
            st.integers(1, rows - 1),  # the first row has no board value
            min_size=1,
            max_size=4,
            unique=True,
        )
    )
    lengths = data.draw(st.lists(st.integers(1, 3), min_size=len(starts), max_size=len(starts)))
    keep = {min(rows - 1, s + k) for s, n in zip(starts, lengths, strict=True) for k in range(n)}
    splice_at = data.draw(st.integers(1, rows - 1))
    later = data.draw(st.sampled_from([0.0, 1e3, 1e6]))
    shift = {i: later for i in range(splice_at, rows)}
    d = _battery_only(real_run, Path(tempfile.mkdtemp(dir=tmp_path)) / "run", keep, shift)
    paths = plot_run(d)
    assert "battery" in paths
    assert _line_pixels(paths["battery"]) > 0
    # each reading's neighbourhood of columns holds the line's colour
    lines = (d / "telemetry.csv").read_text().splitlines()[1:]
    times = np.array([float(line.split(",")[0]) for line in lines])
    lo, hi = times[sorted(keep)].min(), times[sorted(keep)].max()  # the axis spans the numbers drawn
    margin = 0.05 * (hi - lo)  # matplotlib's default x margin
    image = imread(paths["battery"])[AXES_INSIDE][..., :3]
    blue = _of_the_line(image).any(axis=0)  # per pixel column
    width = image.shape[1]
    for i in sorted(keep):
        if hi == lo:  # one time: the axis is centred on it
            column = width / 2
        else:
            column = (times[i] - (lo - margin)) / ((hi + margin) - (lo - margin)) * (width + 4) - 2
        near = blue[max(0, int(column) - 4) : int(column) + 5]
        assert near.any(), f"reading at row {i} (t = {times[i]:g} s) not seen"


FOOT_ROWS = slice(380, 394)  # the rows about the foot of a run figure's axes (its bottom spine at row 387)


def _pointing_only(run_dir: Path, to: Path, zero: range) -> Path:
    """A copy of ``run_dir`` whose telemetry has the time and ``point_err_deg`` only, the error exactly 0
    on the rows of ``zero`` (the spacecraft on its target)."""
    shutil.copytree(run_dir, to)
    lines = (run_dir / "telemetry.csv").read_text().splitlines()
    header = lines[0].split(",")
    t_at, e_at = header.index("t"), header.index("point_err_deg")
    out = ["t,point_err_deg"]
    for i, line in enumerate(lines[1:]):
        cells = line.split(",")
        out.append(f"{cells[t_at]},{'0.0' if i in zero else cells[e_at]}")
    (to / "telemetry.csv").write_text("\n".join(out) + "\n")
    return to


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_pointing_error_of_zero_is_seen_on_its_log_scale(real_run, tmp_path, data):
    """The pointing error exactly 0 over a drawn stretch of rows: its log-scaled figure marks each of
    them at the axes' foot (matplotlib left them out: no data seen where the error was at its best)."""
    rows = _rows(real_run)
    start = data.draw(st.integers(0, rows - 20))
    zero = range(start, start + data.draw(st.integers(10, min(200, rows - start))))
    d = _pointing_only(real_run, Path(tempfile.mkdtemp(dir=tmp_path)) / "run", zero)
    paths = plot_run(d)
    times = np.array(
        [float(line.split(",")[0]) for line in (d / "telemetry.csv").read_text().splitlines()[1:]]
    )
    lo, hi = times.min(), times.max()
    margin = 0.05 * (hi - lo)
    image = imread(paths["pointing_error"])[FOOT_ROWS, AXES_INSIDE[1]][..., :3]
    blue = _of_the_line(image).any(axis=0)
    width = image.shape[1]
    i = zero[len(zero) // 2]
    column = (times[i] - (lo - margin)) / ((hi + margin) - (lo - margin)) * (width + 4) - 2
    assert blue[max(0, int(column) - 4) : int(column) + 5].any(), f"the 0 at t = {times[i]:g} s not seen"

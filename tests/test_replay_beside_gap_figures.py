"""A replay's figures draw the estimates (and, with ground truth, the errors) within the parts of the log the
filter ran over, never a line across a gap between two.

A log split at a gap (docs/formats.md, "Gaps") is replayed part by part, the filter restarted on each; its
figures drew each series as one line, so a 30 s pause showed as a straight line of attitudes and rates no
filter ever estimated, and the error figures drew, over the gap, the error of the two parts' ends joined by
interpolation — the very values the score leaves out (tests/test_logs_beside_absurd_times.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hil.plots.estimator as figures
from hil import so3
from hil.estimation.sensors import SensorLog, SensorStream, StepFlag, Truth
from hil.logs import project_csv, read_log
from hil.logs.replay import ReplayOptions, replay

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


def gapped_log(folder: Path, at_s: float, gap_s: float) -> Path:
    """The 4 s simulated log with its clock jumping by ``gap_s`` after ``at_s``, its truth going on (turning
    about z) through the gap."""
    log = read_log(FIXTURE)
    assert log.truth is not None

    def shift(t: np.ndarray) -> np.ndarray:
        return np.where(t > at_s, t + gap_s, t)

    streams = {k: SensorStream(k, shift(s.t), s.xyz) for k, s in log.streams.items()}
    gap_t = np.arange(at_s + 0.1, at_s + gap_s - 0.05, 0.1)
    gap_r = np.stack(
        [so3.exp(np.array([0.0, 0.0, np.pi * np.sin(np.pi * (t - at_s) / gap_s)])) for t in gap_t]
    )
    t_all = np.r_[shift(log.truth.t), gap_t]
    order = np.argsort(t_all, kind="stable")
    truth = Truth(t_all[order], np.concatenate([log.truth.R, gap_r])[order])
    return project_csv.write(SensorLog(streams, "gap", "csv", truth), folder / "gap.csv")


def drawn_lines(monkeypatch: pytest.MonkeyPatch) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Every line each figure is saved with, by the file's name: (x, y) of each."""
    drawn: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    save = figures._save

    def recording(fig, ax, path):
        drawn[Path(path).name] = [
            (np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)) for line in ax.lines
        ]
        return save(fig, ax, path)

    monkeypatch.setattr(figures, "_save", recording)
    return drawn


def crossings(x: np.ndarray, y: np.ndarray, a: float, b: float) -> int:
    """Segments of a line (consecutive points both drawn) from at or before ``a`` to at or after ``b``, or
    with a point strictly inside (a, b)."""
    drawn = np.isfinite(x) & np.isfinite(y)
    joined = drawn[:-1] & drawn[1:]
    across = joined & (x[:-1] <= a) & (x[1:] >= b)
    inside = drawn & (x > a) & (x < b)
    return int(across.sum() + inside.sum())


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(at_s=st.floats(1.2, 2.8), gap_s=st.floats(3.0, 40.0))
def test_no_figure_draws_a_line_across_a_gap_the_filter_did_not_run_over(
    tmp_path_factory, monkeypatch, at_s, gap_s
):
    folder = tmp_path_factory.mktemp("gap")
    drawn = drawn_lines(monkeypatch)
    result = replay(
        gapped_log(folder, at_s, gap_s),
        ReplayOptions(folder / "o", max_gap_s=1.0, plotter=figures.plot_replay),
    )
    assert [("steps" in segment) for segment in result.segments] == [True, True], result.segments
    t = result.estimates.t
    end = t[t <= result.segments[0]["t1_s"]][-1]  # the first part's last estimate
    start = t[t >= result.segments[1]["t0_s"]][0]  # the second part's first
    assert result.replayed_spans == [(t[0], end), (start, t[-1])]
    assert set(drawn) == {"attitude.png", "rates.png", "attitude_error.png", "rate_error.png"}
    for name, lines in drawn.items():
        assert lines, name
        for x, y in lines:
            assert crossings(x, y, end, start) == 0, (name, end, start)
            assert np.isfinite(y[x <= end]).any() and np.isfinite(y[x >= start]).any(), (
                name
            )  # both parts drawn


def test_the_magnetometers_left_out_intervals_end_at_a_gap(tmp_path):
    """The intervals in which the magnetometer was left out (shaded in the figures, listed in
    ``summary.json``) are each within a part replayed: a part that ended with it left out and the next that
    began so made one interval across the gap, shaded over time no filter ran. Here every step of both parts
    is marked left out: one interval a part, each ending at its part's end."""
    result = replay(gapped_log(tmp_path, 2.0, 10.0), ReplayOptions(tmp_path / "o", max_gap_s=1.0))
    result.estimates.flags[:] |= int(StepFlag.MAG_DISTURBED)
    spans = result.replayed_spans
    assert len(spans) == 2
    assert result.mag_rejections == spans  # not one interval from the first part's start to the last's end

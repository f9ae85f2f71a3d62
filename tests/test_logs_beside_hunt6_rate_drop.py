"""A phone log whose sample rate drops part-way (a hunt's finding): the real Sensor Logger export of
``../shared/data``, its first stretch at its own 50 Hz and the rest thinned to every k-th row (a phone that
throttled its sensors: the screen off, the app in the background).

Every rate the replay judged was a median over the whole log, which the fast stretch sets: the slow
stretch passed unnoticed — its steps are shorter than a gap (no split), the estimator's nominal period
stayed the fast one's (VQF integrates each 0.2 s step as 0.02 s) — and ``hil replay`` said nothing: not
a warning, no count in ``summary.json``. It now warns per sensor, says where and how slow, and counts the
slow steps and seconds (``rate_drops``). A log at its own rate with a few rows lost here and there (phone
jitter) says nothing of the kind.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_export, real_lines

from hil.logs.replay import ReplayOptions, replay

pytestmark = needs_real_export
LINES = 3001  # the header and ~60 s of each file at 50 Hz
TMP = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]


def thinned(keep_rows: int, every: int, lost: frozenset[int] = frozenset()):
    """An edit for :func:`real_export`: the header and the first ``keep_rows`` rows as recorded, every
    ``every``-th row after them, and the rows numbered in ``lost`` left out (a lost sample)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        rows = [r for i, r in enumerate(lines[1:]) if i not in lost]
        return [lines[0], *rows[:keep_rows], *rows[keep_rows::every]]

    return edit


def export(folder: Path, edit) -> Path:
    """The real export cut to :data:`LINES` lines a file, edited."""
    return real_export(folder, lambda name, _short: edit(name, real_lines(name, LINES)))


@settings(max_examples=6, deadline=None, suppress_health_check=TMP)
@given(
    fast_s=st.floats(min_value=5.0, max_value=45.0),
    every=st.integers(min_value=3, max_value=20),
)
def test_a_rate_that_drops_part_way_is_warned_and_counted(tmp_path: Path, fast_s: float, every: int) -> None:
    folder = export(tmp_path / f"log-{fast_s:.3f}-{every}", thinned(int(fast_s * 50), every))
    result = replay(folder, ReplayOptions(out_dir=folder / "out"))
    said = [w for w in result.warnings if "rate drops" in w]
    assert {w.split(":")[0] for w in said} == {"gyr", "acc", "mag"}, result.warnings
    summary = json.loads((folder / "out" / "summary.json").read_text())
    for label in ("gyr", "acc", "mag"):
        drop = summary["rate_drops"][label]
        assert drop["first_slow_s"] == pytest.approx(fast_s, abs=1.0)  # where it slowed
        assert drop["slow_s"] == pytest.approx(60.0 - fast_s, abs=2.0)  # for how long
        assert drop["slowest_hz"] == pytest.approx(50.0 / every, rel=0.2)  # how slow
        assert drop["rate_hz"] == pytest.approx(50.0, rel=0.05)  # its own rate


@settings(max_examples=4, deadline=None, suppress_health_check=TMP)
@given(lost=st.frozensets(st.integers(min_value=1, max_value=2990), max_size=60))
def test_lone_lost_rows_are_no_rate_drop(tmp_path: Path, lost: frozenset[int]) -> None:
    """Rows lost one by one (no two within a few steps of each other are needed: a lone miss moves a run's
    mean step by a ninth) at the log's own rate: no rate drop said."""
    spaced = frozenset(i for i in lost if not any(j in lost for j in range(i - 9, i)))
    folder = export(tmp_path / f"log-{len(lost)}-{hash(lost) & 0xFFFF}", thinned(LINES, 1, spaced))
    result = replay(folder, ReplayOptions(out_dir=folder / "out"))
    assert not [w for w in result.warnings if "rate drops" in w]
    assert json.loads((folder / "out" / "summary.json").read_text())["rate_drops"] == {}


def test_hil_replay_says_the_rate_drop(tmp_path: Path) -> None:
    """Through the real command: the export's 50 Hz for 30 s, 5 Hz after."""
    folder = export(tmp_path / "log", thinned(1500, 10))
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(folder), "--out", str(out), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    text = done.stdout + done.stderr
    for label in ("gyr", "acc", "mag"):
        assert f"{label}: its rate drops part-way through the log" in text
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["rate_drops"]) == {"gyr", "acc", "mag"}
    for drop in summary["rate_drops"].values():
        assert drop["slowest_hz"] == pytest.approx(5.0, rel=0.1)
        assert f"as slow as {drop['slowest_hz']:.3g} Hz" in text
    assert any("rate drops" in w for w in summary["warnings"])

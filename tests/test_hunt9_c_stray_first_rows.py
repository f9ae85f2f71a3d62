"""A phone export with a stray row stamped far from the recording — first in its file, or behind the
recording's start — is replayed, the stray counted in a part of its own, through ``hil replay``.

Before: a stray *in the middle* or *last* was already a one-sample part, left out and counted; beside it,

- a stray **first** row stamped far ahead (1e160 s, or a day on) was taken for a first stretch of the
  recording and everything after it for a restarted one: the recording was cut to that one row and the
  replay refused — "the accelerometer has 1 reading(s) with a time (at 1e+160 s): fewer than 2 span no
  time";
- a stray stamped far **behind** the recording (-1e5 s, -1e160 s), anywhere in its file, became the log's
  start, where the still window and the inertial directions are measured from: "too few magnetometer
  samples in the first 10 s (1, at least 5 needed)".

Drawn: the stray's value, its row (first or inside), and which of the files hold one. The export is a
phyphox experiment (one clock, ``Time (s)``) built from the real Sensor Logger recording.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.logs.replay import ReplayOptions, replay
from tests.log_support import needs_real_export, real_lines

pytestmark = needs_real_export

SOURCES = {  # phyphox's file → (the real export's file, its unit)
    "Accelerometer.csv": ("TotalAcceleration.csv", "m/s^2"),
    "Gyroscope.csv": ("Gyroscope.csv", "rad/s"),
    "Magnetometer.csv": ("Magnetometer.csv", "µT"),
}
STRAYS = ["1E160", "-1E160", "86400", "-100000", "-3600"]


def _phyphox(folder: Path, strays: dict[str, tuple[int, str]]) -> Path:
    """A phyphox experiment of the real recording's first ~8 s; ``strays``: file → (data row the stray
    is written before, its time in s)."""
    folder.mkdir(parents=True)
    for name, (source, unit) in SOURCES.items():
        rows = []
        for line in real_lines(source)[1:]:
            _, elapsed, z, y, x = line.split(",")
            rows.append(f"{float(elapsed):.9E},{x},{y},{z}")
        if name in strays:
            at, value = strays[name]
            rows.insert(at, f"{value},{rows[at].split(',', 1)[1]}")
        header = f'"Time (s)","X ({unit})","Y ({unit})","Z ({unit})"'
        (folder / name).write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return folder


_CLEAN: list[int] = []


def _clean_steps(tmp_path_factory: pytest.TempPathFactory) -> int:
    """The estimates of the export without a stray, replayed once for every example."""
    if not _CLEAN:
        folder = tmp_path_factory.mktemp("clean")
        _CLEAN.append(
            len(replay(_phyphox(folder / "log", {}), ReplayOptions(out_dir=folder / "out")).estimates)
        )
    return _CLEAN[0]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    files=st.sets(st.sampled_from(sorted(SOURCES)), min_size=1),
    first=st.booleans(),
    inside=st.integers(1, 390),
    value=st.sampled_from(STRAYS),
)
def test_a_stray_row_is_left_out_and_the_recording_replayed(
    tmp_path_factory: pytest.TempPathFactory, files: set[str], first: bool, inside: int, value: str
) -> None:
    clean = _clean_steps(tmp_path_factory)
    folder = tmp_path_factory.mktemp("stray")
    export = _phyphox(folder / "log", {name: (0 if first else inside, value) for name in files})
    result = replay(export, ReplayOptions(out_dir=folder / "out"))
    assert sum(result.skipped_parts.values()) == len(files), result.warnings  # each stray counted
    assert len(result.estimates) >= clean - len(files), (len(result.estimates), clean)  # the rest replayed
    assert any("not replayed" in w for w in result.warnings), result.warnings


@pytest.mark.parametrize("value", ["1E160", "-100000"])
def test_hil_replay_of_a_stray_first_row(tmp_path: Path, value: str) -> None:
    export = _phyphox(tmp_path / "log", {name: (0, value) for name in SOURCES})
    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(export), "--no-plots", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "its 3 samples are left out (acc 1, gyr 1, mag 1)" in done.stdout, done.stdout
    assert (tmp_path / "out" / "estimates.csv").is_file()

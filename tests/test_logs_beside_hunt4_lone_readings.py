"""``hil replay`` of an export one of whose sensors says almost nothing: a file of one row beside normal
ones (any sensor, any row of the recording), and streams that overlap in time by one sample only.

Before: a gyroscope file of one row beside 8 s of the others replayed ~400 estimator steps on the others'
samples, its one reading held stale, and exit 0; an accelerometer of one row was refused as "too few
magnetometer samples"; a gyroscope that ends where the accelerometer starts replayed the accelerometer's
whole stretch without a gyroscope. The exports are the shared recording cut short (read, never copied)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from tests.log_support import REAL_LINES, needs_real_export, real_export

SENSORS = {
    "Gyroscope.csv": "gyroscope",
    "TotalAcceleration.csv": "accelerometer",
    "Magnetometer.csv": "magnetometer",
}
SETTINGS = settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@needs_real_export
@SETTINGS
@given(name=st.sampled_from(sorted(SENSORS)), row=st.integers(1, REAL_LINES - 1))
def test_a_sensor_file_of_one_row_is_an_error_naming_it(tmp_path, capsys, name, row):
    """One row (any of the recording's) left in one sensor's file: an error naming that file and sensor,
    never a replay of the others with that sensor held stale."""
    out = Path(tempfile.mkdtemp(dir=tmp_path))  # a folder per example: Hypothesis calls it again
    log = real_export(out / "log", lambda n, lines: [lines[0], lines[row]] if n == name else lines)
    status = main(["replay", str(log), "--out", str(out / "run"), "--no-plots"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert f"the {SENSORS[name]} has 1 reading(s) with a time" in err, err
    assert str(log / name) in err or name in err, err
    assert not (out / "run" / "estimates.csv").exists()


def write_csv(path, gyr_span, acc_span, mag_span=(0.0, 8.0), rate=50.0):
    """A still phone in the project's CSV (docs/formats.md), each sensor at ``rate`` Hz over its own
    ``[t0, t1]`` span (s), both ends included."""
    rng = np.random.default_rng(5)
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    for t in np.arange(0.0, 8.0 + 1e-9, 1.0 / rate):
        if gyr_span[0] <= t <= gyr_span[1]:
            g = rng.normal(0.0, 1e-3, 3)
            lines.append(f"{t:.6f},gyr,{g[0]:.6f},{g[1]:.6f},{g[2]:.6f},")
        if acc_span[0] <= t <= acc_span[1]:
            a = rng.normal(0.0, 1e-2, 2)
            lines.append(f"{t:.6f},acc,{a[0]:.5f},{a[1]:.5f},9.81,")
        if mag_span[0] <= t <= mag_span[1]:
            lines.append(f"{t:.6f},mag,20.0,5.0,-40.0,")
    path.write_text("\n".join(lines) + "\n")
    return path


@SETTINGS
@given(meet=st.sampled_from([1.0, 2.5, 4.0, 6.0]), gyro_first=st.booleans())
def test_streams_that_overlap_by_one_sample_are_not_replayed(tmp_path, capsys, meet, gyro_first):
    """The gyroscope up to ``meet`` s and the accelerometer from it (or the other way round), the
    magnetometer all along: one step has both; no part is replayed, and the error says which ended."""
    out = Path(tempfile.mkdtemp(dir=tmp_path))
    early, late = (0.0, meet), (meet, 8.0)
    spans = (early, late) if gyro_first else (late, early)
    log = write_csv(out / "log.csv", *spans)
    status = main(["replay", str(log), "--out", str(out / "run"), "--no-plots"])
    err = capsys.readouterr().err
    assert status == 2, err
    ended = "gyroscope" if gyro_first else "accelerometer"
    assert f"the log's {ended} ends at {meet:.3f} s" in err, err


def test_a_gyroscope_ending_early_replays_up_to_its_end_and_counts_the_rest(tmp_path, capsys):
    """The gyroscope stops at 5 s of 8: the estimates end there, and the samples after are said and
    counted in ``summary.json`` (``skipped_parts``), never estimated on the accelerometer alone."""
    log = write_csv(tmp_path / "log.csv", (0.0, 5.0), (0.0, 8.0))
    out = tmp_path / "run"
    assert main(["replay", str(log), "--out", str(out), "--no-plots"]) == 0
    said = capsys.readouterr().out
    assert "the log's gyroscope ends at 5.000 s" in said, said
    rows = (out / "estimates.csv").read_text().splitlines()[2:]
    assert float(rows[-1].split(",")[0]) <= 5.0 + 1e-9
    summary = json.loads((out / "summary.json").read_text())
    assert any("gyroscope ends at 5.000 s" in w for w in summary["warnings"])
    assert not any(w.startswith("gyr: stale") for w in summary["warnings"]), summary["warnings"]


def phyphox_table(path: Path, label: str, unit: str, z: float) -> None:
    """One phyphox table of a still phone, 8 s at 100 Hz, as phyphox writes it."""
    lines = [",".join(f'"{c}"' for c in ("Time (s)", *(f"{label} {a} ({unit})" for a in "xyz")))]
    lines += [f"{t:.9E},{0.01:.9E},{0.02:.9E},{z:.9E}" for t in np.arange(0.0, 8.0, 0.01)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    ("file", "label", "unit", "missing"),
    [
        ("Raw Data.csv", "Gyroscope", "rad/s", "accelerometer"),  # a built-in single-sensor export
        ("Gyroscope.csv", "Gyroscope", "rad/s", "accelerometer"),
        ("Accelerometer.csv", "Acceleration", "m/s^2", "gyroscope"),
    ],
)
def test_a_phyphox_export_of_one_sensor_is_an_error_naming_what_is_missing(
    tmp_path, capsys, file, label, unit, missing
):
    """One table only: an error naming the sensor missing and what the table holds, and how to give both."""
    phyphox_table(tmp_path / "export" / file, label, unit, 9.81 if missing == "gyroscope" else 0.001)
    status = main(["replay", str(tmp_path / "export"), "--out", str(tmp_path / "run"), "--no-plots"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert f"no {missing} file (found {file}: " in err and "each sensor's export in one folder" in err, err

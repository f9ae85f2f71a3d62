"""A phyphox experiment export (one experiment, several sensors: ``Accelerometer.csv``, ``Gyroscope.csv``,
``Magnetometer.csv``) recorded, paused, and resumed. phyphox's experiment time — the ``Time (s)`` of every
table — stands still while the experiment is paused; only ``meta/time.csv`` (``START``/``PAUSE`` rows with
their system times) says that the motion after the resume happened later. That file was read only to
align several exports; a single export's was never opened, so a recording paused for minutes read as
one unbroken stretch: the replay integrated straight across the pause, joining the motion before and
after it, with no gap and no word. Now a single export's pauses are placed as several exports' are."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_phone_exports import HEAD, motion, phyphox_csv

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
START_S = 1_714_550_400.0  # 2024-05-01, the system time of the first START
FILES = {ACC: "Accelerometer.csv", GYR: "Gyroscope.csv", MAG: "Magnetometer.csv"}


def paused_experiment(
    folder: Path,
    pause_at_s: float,
    pause_s: float,
    n: int = 400,
    delimiter: str = ",",
    decimal: str = ".",
    zipped: bool = False,
) -> Path:
    """One experiment's export, paused at experiment time ``pause_at_s`` for ``pause_s`` (wall-clock s)
    and resumed to its end: its tables on the experiment's clock (which stands still while paused),
    ``meta/time.csv`` with START, PAUSE, START, PAUSE in the export's dialect, as phyphox writes it."""
    t, gyr, acc, mag = motion(n=n)
    for kind, xyz in ((ACC, acc), (GYR, gyr), (MAG, mag)):
        phyphox_csv(folder / FILES[kind], ("Time (s)", *HEAD[kind]), t, xyz, delimiter, decimal)
    end = float(t[-1])
    events = [
        ("START", 0.0, START_S),
        ("PAUSE", pause_at_s, START_S + pause_at_s),
        ("START", pause_at_s, START_S + pause_at_s + pause_s),
        ("PAUSE", end, START_S + end + pause_s),
    ]
    rows = ['"event"', '"experiment time"', '"system time"', '"system time text"']
    lines = [delimiter.join(rows)]
    for event, experiment, system in events:
        cells = (f'"{event}"', f"{experiment:.9E}", f"{system:.3f}", '"2024-05-01 10:00:00.000 UTC+02:00"')
        lines.append(delimiter.join(cell.replace(".", decimal) for cell in cells))
    (folder / "meta").mkdir()
    (folder / "meta" / "time.csv").write_text("\n".join(lines) + "\n")
    (folder / "meta" / "device.csv").write_text('"property","value"\n"deviceModel","test"\n')
    if not zipped:
        return folder
    archive = folder.with_suffix(".zip")
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    return archive


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    pause_at_s=st.floats(0.2, 3.8),
    pause_s=st.floats(0.5, 3600.0),
    dialect=st.sampled_from([(",", "."), (";", ","), ("\t", "."), ("\t", ",")]),
    zipped=st.booleans(),
)
def test_a_single_experiment_paused_and_resumed_places_each_stretch_and_says_so(
    tmp_path_factory, pause_at_s, pause_s, dialect, zipped
):
    """Every sensor's samples after the resume lie ``pause_s`` later than their experiment time, those
    before it where they were; the pause is noted."""
    path = paused_experiment(
        tmp_path_factory.mktemp("exp") / "Experiment",
        pause_at_s,
        pause_s,
        delimiter=dialect[0],
        decimal=dialect[1],
        zipped=zipped,
    )
    log = read_log(path)
    t_experiment = motion()[0]
    after = t_experiment > pause_at_s + 1e-6
    before = t_experiment < pause_at_s - 1e-6  # a sample at the very moment of the pause: either stretch
    for kind in (ACC, GYR, MAG):
        t = log.streams[kind].t
        np.testing.assert_allclose(t[before], t_experiment[before], atol=1e-6)
        np.testing.assert_allclose(t[after], t_experiment[after] + pause_s, atol=2e-3)
    assert any("paused and resumed 1 time(s)" in n for n in log.notes), log.notes


def test_hil_replay_splits_a_paused_experiment_at_its_pause(tmp_path):
    """``hil replay`` of the paused export: two parts, the second after a gap of the pause (it was one
    part, integrated across 60 s the phone moved unrecorded)."""
    folder = paused_experiment(tmp_path / "Experiment", 5.0, 60.0, n=1000)
    out = tmp_path / "out"
    assert main(["replay", str(folder), "--out", str(out), "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    segments = summary["segments"]
    assert len(segments) == 2, segments
    assert segments[1]["gap_before_s"] == pytest.approx(60.0, abs=0.05)


def test_a_single_experiment_without_meta_time_reads_on_its_own_clock(tmp_path):
    """No ``meta/time.csv`` (a custom experiment's buffers, a folder of the tables alone): read as ever."""
    folder = paused_experiment(tmp_path / "Experiment", 2.0, 30.0)
    (folder / "meta" / "time.csv").unlink()
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[GYR].t, motion()[0], atol=1e-9)


def test_a_single_experiments_unreadable_meta_time_is_noted_and_its_tables_read(tmp_path):
    """A ``meta/time.csv`` another app version laid out otherwise (no START row): the tables share one
    clock and are read on it, the file named in a note saying a pause is not placed."""
    folder = paused_experiment(tmp_path / "Experiment", 2.0, 30.0)
    (folder / "meta" / "time.csv").write_text('"event","experiment time","system time"\n"PAUSE",4.0,1.0\n')
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[GYR].t, motion()[0], atol=1e-9)
    assert any("meta/time.csv" in n and "not placed" in n for n in log.notes), log.notes

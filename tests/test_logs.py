"""Log readers: every format through its real files, units and frames normalised, errors that say where."""

from __future__ import annotations

import gzip
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.world.models import Trajectory, paper_testbed_rate, simulate
from hil import so3
from hil.estimation.multirate import merge
from hil.estimation.sensors import SensorKind, SensorLog, Truth
from hil.logs import detect_format, project_csv, read_log
from hil.scenario.paths import FIXTURES, SHARED_DATA
from hil.scenario.phone import PhoneSpec
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
MALFORMED = FIXTURES / "logs" / "malformed"
SENSORLOGGER = SHARED_DATA / "sensorlogger-android"
TYREX = SHARED_DATA / "tyrex-nexus5"
BROAD = SHARED_DATA / "broad"


# --------------------------------------------------------------------------- malformed corpus
MANIFEST = {
    k: v for k, v in json.loads((MALFORMED / "MANIFEST.json").read_text()).items() if not k.startswith("_")
}


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_malformed_log_names_file_line_and_column(name):
    expected = MANIFEST[name]
    with pytest.raises(InputFormatError) as info:
        read_log(MALFORMED / name)
    err = info.value
    assert expected["file"] in err.path
    assert err.line == expected["line"]
    assert err.column == expected["column"]
    assert expected["file"] in str(err)


def test_unknown_folder_and_missing_path_are_input_format_errors(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputFormatError, match="not a recognised log"):
        detect_format(tmp_path)
    with pytest.raises(InputFormatError, match="no such file"):
        read_log(tmp_path / "missing.csv")
    with pytest.raises(InputFormatError, match="unknown format"):
        read_log(tmp_path, format="garmin")


# --------------------------------------------------------------------------- project CSV
def simulated_log(seconds: float = 1.0) -> SensorLog:
    traj = Trajectory.from_rate(paper_testbed_rate, seconds, R0=so3.exp([0.3, -0.2, 0.5]), dt=1e-3)
    log = simulate(traj, PhoneSpec.nexus5(), seed=4)
    return SensorLog(log.streams, "sim", "simulated", Truth(traj.t[::10], traj.R[::10]))


def test_project_csv_round_trip_with_truth(tmp_path):
    log = simulated_log()
    path = project_csv.write(log, tmp_path / "log.csv")
    assert detect_format(path) == "csv"
    back = read_log(path)
    for kind in SensorKind:
        np.testing.assert_allclose(back.streams[kind].t, log.streams[kind].t, atol=1e-9)
        np.testing.assert_allclose(back.streams[kind].xyz, log.streams[kind].xyz, rtol=1e-9, atol=1e-12)
    assert back.truth is not None and log.truth is not None
    np.testing.assert_allclose(back.truth.R, log.truth.R, atol=1e-9)


def test_the_fixture_log_reads_and_nan_samples_are_counted_not_fatal(tmp_path):
    text = (FIXTURES / "logs" / "simulated_testbed_4s.csv").read_text()
    lines = text.splitlines()
    gyr_rows = [i for i, line in enumerate(lines) if ",gyr," in line]
    for i in gyr_rows[10:13]:
        t = lines[i].split(",")[0]
        lines[i] = f"{t},gyr,nan,0.1,0.2,"
    path = tmp_path / "with_nan.csv"
    path.write_text("\n".join(lines) + "\n")
    log = read_log(path)
    _, stats = merge(log.streams)
    assert stats.nan["gyr"] == 3
    assert len(log.streams[GYR]) == len(gyr_rows)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_corrupted_project_csv_reads_or_raises_input_format_error(tmp_path, data):
    """Any byte-level damage to a valid log either still parses or raises InputFormatError — never
    another exception, never a hang."""
    text = (FIXTURES / "logs" / "simulated_testbed_4s.csv").read_text().splitlines()[:60]
    body = bytearray("\n".join(text).encode())
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(body) - 1))
        body[i] = data.draw(st.sampled_from(b"x,.-9\n e;\x00\xff"))
    path = tmp_path / "damaged.csv"
    path.write_bytes(bytes(body))
    try:
        log = read_log(path, format="csv")
    except InputFormatError as exc:
        assert exc.path
        return
    assert all(s.xyz.shape[1] == 3 for s in log.streams.values())


# --------------------------------------------------------------------------- Sensor Logger
def sensorlogger_export(folder: Path, with_total: bool = True, with_gravity: bool = False) -> Path:
    """A tiny Sensor Logger export; the values make the z, y, x order visible (x = 1, y = 2, z = 3)."""
    folder.mkdir()
    head = "time,seconds_elapsed,z,y,x\n"
    t0 = 1_679_068_247_000_000_000

    def rows(offset_ns: int, z: float, y: float, x: float, n: int = 20) -> str:
        return "".join(f"{t0 + offset_ns + k * 20_000_000},{k * 0.02},{z},{y},{x}\n" for k in range(n))

    (folder / "Gyroscope.csv").write_text(head + rows(5_000_000, 0.3, 0.2, 0.1))
    (folder / "Magnetometer.csv").write_text(head + rows(7_000_000, -40.0, 20.0, 1.0))
    if with_total:
        (folder / "TotalAcceleration.csv").write_text(head + rows(0, 9.8, 0.2, 0.1))
    else:
        (folder / "Accelerometer.csv").write_text(head + rows(0, 0.5, 0.2, 0.1))
    if with_gravity:
        (folder / "Gravity.csv").write_text(head + rows(0, 9.3, 0.0, 0.0))
    return folder


def test_sensorlogger_columns_are_read_by_name_and_times_share_one_origin(tmp_path):
    log = read_log(sensorlogger_export(tmp_path / "export"))
    assert log.format == "sensorlogger"
    np.testing.assert_allclose(log.streams[GYR].xyz[0], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(log.streams[MAG].xyz[0], [1.0, 20.0, -40.0])
    np.testing.assert_allclose(log.streams[ACC].t[:2], [0.0, 0.02], atol=1e-9)
    np.testing.assert_allclose(log.streams[GYR].t[0], 0.005, atol=1e-9)


def test_sensorlogger_zip_reads_like_the_folder(tmp_path):
    folder = sensorlogger_export(tmp_path / "export")
    archive = tmp_path / "export.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in folder.iterdir():
            z.write(f, f"Recording_2023/{f.name}")
    a, b = read_log(folder), read_log(archive)
    for kind in SensorKind:
        np.testing.assert_array_equal(a.streams[kind].xyz, b.streams[kind].xyz)
        np.testing.assert_array_equal(a.streams[kind].t, b.streams[kind].t)


def test_sensorlogger_user_acceleration_plus_gravity_or_refusal(tmp_path):
    log = read_log(sensorlogger_export(tmp_path / "a", with_total=False, with_gravity=True))
    np.testing.assert_allclose(log.streams[ACC].xyz[0], [0.1, 0.2, 9.8])
    assert any("Gravity.csv" in n for n in log.notes)
    with pytest.raises(InputFormatError, match="gravity"):
        read_log(sensorlogger_export(tmp_path / "b", with_total=False))


def test_the_real_sensorlogger_export_reads_at_50_hz_with_gravity_and_the_earth_field():
    log = read_log(SENSORLOGGER)
    assert {k: len(s) for k, s in log.streams.items()} == {GYR: 34648, ACC: 34667, MAG: 34650}
    for kind in SensorKind:
        assert 1 / log.streams[kind].median_period() == pytest.approx(50.0, rel=0.02)
    first = (SENSORLOGGER / "Gyroscope.csv").read_text().splitlines()[1].split(",")
    np.testing.assert_allclose(log.streams[GYR].xyz[0], [float(first[4]), float(first[3]), float(first[2])])
    assert np.median(np.linalg.norm(log.streams[ACC].xyz, axis=1)) == pytest.approx(9.8, abs=0.3)
    assert 20 < np.median(np.linalg.norm(log.streams[MAG].xyz, axis=1)) < 70


# --------------------------------------------------------------------------- phyphox
PHYPHOX_HEADERS = {
    "Accelerometer.csv": ("Acceleration x (m/s^2)", "Acceleration y (m/s^2)", "Acceleration z (m/s^2)"),
    "Gyroscope.csv": ("Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)"),
    "Magnetometer.csv": ("Magnetic field x (µT)", "Magnetic field y (µT)", "Magnetic field z (µT)"),
}


def phyphox_export(folder: Path, delimiter: str, decimal: str, gyro_unit: str = "rad/s") -> Path:
    folder.mkdir()
    values = {
        "Accelerometer.csv": (0.5, -0.25, 9.75),
        "Gyroscope.csv": (0.125, 0.0, -2.5),
        "Magnetometer.csv": (1.5, 20.0, -40.0),
    }
    for name, cols in PHYPHOX_HEADERS.items():
        cols = tuple(c.replace("rad/s", gyro_unit) for c in cols)
        lines = [delimiter.join(f'"{c}"' for c in ("Time (s)", *cols))]
        for k in range(10):
            row = (0.01 * k + 0.001 * len(name), *values[name])
            lines.append(delimiter.join(f"{v:.6f}".replace(".", decimal) for v in row))
        (folder / name).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


@pytest.mark.parametrize(("delimiter", "decimal"), [(",", "."), ("\t", "."), (";", ",")])
def test_phyphox_three_csv_dialects(tmp_path, delimiter, decimal):
    log = read_log(phyphox_export(tmp_path / "p", delimiter, decimal))
    assert log.format == "phyphox"
    np.testing.assert_allclose(log.streams[ACC].xyz[0], [0.5, -0.25, 9.75])
    np.testing.assert_allclose(log.streams[GYR].xyz[3], [0.125, 0.0, -2.5])
    np.testing.assert_allclose(log.streams[MAG].t[:2], [0.016, 0.026])


def test_phyphox_units_are_converted_and_zip_is_read(tmp_path):
    folder = phyphox_export(tmp_path / "p", ",", ".", gyro_unit="°/s")
    archive = tmp_path / "phyphox.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in folder.iterdir():
            z.write(f, f.name)
    log = read_log(archive)
    np.testing.assert_allclose(log.streams[GYR].xyz[0], np.radians([0.125, 0.0, -2.5]))


def test_phyphox_linear_acceleration_only_is_refused(tmp_path):
    folder = phyphox_export(tmp_path / "p", ",", ".")
    (folder / "Accelerometer.csv").rename(folder / "Linear Acceleration.csv")
    with pytest.raises(InputFormatError, match="gravity"):
        read_log(folder, format="phyphox")


@pytest.mark.parametrize(
    ("start", "refused"),
    [
        (0.0, False),  # the experiment's clock
        (1.7e9, False),  # a custom experiment counting seconds since the epoch
        (1.5e10, True),  # ns since the phone booted, 15 s up (a Sensor Logger file, --format phyphox)
        (9e10, True),  # the same 90 s up: read as seconds, once replayed as samples 3000 years on
        (1.7e12, True),  # an epoch in ms
    ],
)
def test_phyphox_times_that_are_no_seconds_are_refused_naming_the_column(tmp_path, start, refused):
    folder = phyphox_export(tmp_path / "p", ",", ".")
    for f in folder.iterdir():
        lines = f.read_text().splitlines()
        rows = [line.split(",") for line in lines[1:]]
        shifted = [
            ",".join([repr(start + float(r[0]) * (1e9 if start > 1e10 else 1.0)), *r[1:]]) for r in rows
        ]
        f.write_text("\n".join([lines[0], *shifted]) + "\n")
    if not refused:
        log = read_log(folder, format="phyphox")
        np.testing.assert_allclose(log.streams[MAG].t[:2] - log.streams[MAG].t[0], [0.0, 0.01], atol=1e-6)
        return
    with pytest.raises(InputFormatError, match="no experiment time") as err:
        read_log(folder, format="phyphox")
    assert err.value.column == "Time (s)"


# --------------------------------------------------------------------------- tyrex and BROAD (real files)
def test_tyrex_trial_rates_and_truth_on_the_phone_clock():
    trial = TYREX / "Guillaume_Nexus5_NoDist_Texting"
    log = read_log(trial)
    assert log.format == "tyrex" and log.truth is not None
    assert 1 / log.streams[MAG].median_period() == pytest.approx(49.6, rel=0.01)
    assert 1 / log.streams[GYR].median_period() == pytest.approx(198.6, rel=0.01)
    offset = float((trial / "timeAlignment.txt").read_text())
    assert log.truth.t[0] == pytest.approx(-offset)
    # the truth's rotation rate and the gyroscope agree best with no extra lag: the alignment is right
    from hil.estimation.metrics import truth_rates

    mid, w_true = truth_rates(log.truth.t, log.truth.R)
    gyr = log.streams[GYR]
    sel = (mid > gyr.t[0] + 1) & (mid < gyr.t[-1] - 1) & np.all(np.isfinite(w_true), axis=1)
    lags = np.arange(-0.1, 0.1001, 0.01)

    def mismatch(lag: float) -> float:
        w_gyr = np.column_stack([np.interp(mid[sel] + lag, gyr.t, gyr.xyz[:, i]) for i in range(3)])
        return float(np.nanmean(np.linalg.norm(w_gyr - w_true[sel], axis=1)))

    err = [mismatch(lag) for lag in lags]
    assert abs(lags[int(np.argmin(err))]) <= 0.02


def test_tyrex_excluded_intervals_are_not_evaluated():
    log = read_log(TYREX / "Guillaume_Nexus5_NoDist_AR")
    truth = log.truth
    assert truth is not None
    offset = float((TYREX / "Guillaume_Nexus5_NoDist_AR" / "timeAlignment.txt").read_text())
    mocap = truth.t + offset
    assert not truth.evaluate[(mocap > 64.0) & (mocap < 120.0)].any()
    assert truth.evaluate[(mocap > 1.0) & (mocap < 63.0)].mean() > 0.95


def test_broad_trial_with_truth_and_movement_mask():
    log = read_log(BROAD / "01_undisturbed_slow_rotation_A.mat")
    assert log.format == "broad" and log.truth is not None
    assert len(log.truth) == len(log.streams[GYR]) == 56940
    assert 0.5 < log.truth.evaluate.mean() < 0.7
    assert so3.is_rotation(log.truth.R[1000], 1e-9)


def test_truncated_and_non_text_files_are_input_format_errors(tmp_path):
    folder = tmp_path / "trial"
    folder.mkdir()
    (folder / "accelerometer.txt.gz").write_bytes(gzip.compress(b"0.1 0.0 0.0 9.8\n0.2 0.0 0.0\n"))
    (folder / "gyroscope-calibrated.txt.gz").write_bytes(gzip.compress(b"0.1 0.0 0.0 0.0\n"))
    (folder / "magnetometer-calibrated.txt.gz").write_bytes(gzip.compress(b"0.1 1.0 20.0 -40.0\n"))
    with pytest.raises(InputFormatError) as info:
        read_log(folder)
    assert info.value.line == 2 and "accelerometer" in info.value.path
    bad = tmp_path / "bin.csv"
    bad.write_bytes(b"# vscmg-hil sensor log v1\nt_s,sensor,x,y,z,w\n\xff\xfe,gyr\n")
    with pytest.raises(InputFormatError, match="UTF-8"):
        read_log(bad)


@pytest.mark.parametrize("folder", [TYREX, BROAD], ids=["tyrex", "broad"])
def test_a_folder_of_trials_is_refused_with_one_trial_suggested(folder):
    """``hil replay`` given the folder of a benchmark's trials, not one trial: the error names a trial to
    replay and how many more there are (it said only "not a recognised log")."""
    with pytest.raises(InputFormatError) as err:
        read_log(folder)
    message = str(err.value)
    trials = sorted(p for p in folder.iterdir() if p.name not in ("trials.json", "LICENCE"))
    assert f"replay one, e.g. {trials[0]}" in message and f"and {len(trials) - 1} more" in message
    assert detect_format(trials[0]) in ("tyrex", "broad")


def test_a_folder_of_other_things_gets_no_suggestion(tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("hello\n")
    (tmp_path / "b.csv").write_text("x,y\n1,2\n")
    with pytest.raises(InputFormatError) as err:
        read_log(tmp_path)
    assert "not a recognised log" in str(err.value) and "replay one" not in str(err.value)

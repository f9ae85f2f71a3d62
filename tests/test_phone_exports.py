"""Real phone exports as users bring them, each built here in its app's documented layout (docs/formats.md
lists every layout and its test): Sensor Logger current, older and uncalibrated-only; phyphox experiment
files, built-in single-sensor exports aligned by meta/time.csv, custom buffers, every CSV dialect; 6-axis
recordings (no magnetometer) replayed with heading reported unobserved; refusals that say what to do."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from hil import so3
from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from hil.logs.replay import ReplayOptions, replay
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
T0_NS = 1_669_000_000_000_000_000  # late 2022
N = 400  # samples per sensor: 4 s at 100 Hz


def motion(
    n: int = N, dt: float = 0.01, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A phone lying flat, then turning about its z axis at 0.5 rad/s: times, gyro, acc (+g), mag."""
    t = offset + dt * np.arange(n)
    rate = np.where(t > 1.0, 0.5, 0.0)
    yaw = np.cumsum(rate) * dt
    gyr = np.column_stack([np.zeros(n), np.zeros(n), rate])
    acc = np.tile([0.05, -0.02, 9.80665], (n, 1))
    field = np.array([0.0, 20.0, -40.0])  # north and down in ENU: body = R(yaw)^T field
    mag = np.array([so3.exp([0, 0, y]).T @ field for y in yaw])
    return t, gyr, acc, mag


# --------------------------------------------------------------------------- Sensor Logger
def sensor_logger(folder: Path, files: dict[str, np.ndarray], header: str = "zyx") -> Path:
    """Files in Sensor Logger's layout: ``time`` (epoch ns), ``seconds_elapsed``, then the axes; current
    exports name them ``z,y,x``; ``header="old"`` names them like ``GYROSCOPE X (rad/s)`` (late 2022)."""
    folder.mkdir(parents=True)
    old = {
        "Gyroscope": ("GYROSCOPE", "rad/s"),
        "TotalAcceleration": ("ACCELERATION", "m/s^2"),
        "Magnetometer": ("MAGNETIC FIELD", "µT"),
    }
    t, _, _, _ = motion()
    for name, xyz in files.items():
        if header == "old":
            label, unit = old.get(name.removesuffix("Uncalibrated"), old.get(name, (name.upper(), "")))
            unit = f" ({unit})" if unit else ""
            cols = [f"{label} {a}{unit}" for a in "XYZ"]
            rows = [
                f"{T0_NS + int(ti * 1e9)},{ti:.4f},{x:.6f},{y:.6f},{z:.6f}"
                for ti, (x, y, z) in zip(t, xyz, strict=True)
            ]
            head = "time,seconds_elapsed," + ",".join(cols)
        else:
            rows = [
                f"{T0_NS + int(ti * 1e9)},{ti:.4f},{z:.6f},{y:.6f},{x:.6f}"
                for ti, (x, y, z) in zip(t, xyz, strict=True)
            ]
            head = "time,seconds_elapsed,z,y,x"
        (folder / f"{name}.csv").write_text(head + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return folder


def test_sensor_logger_without_a_magnetometer_replays_6_axis_with_heading_unobserved(tmp_path):
    _, gyr, acc, _ = motion()
    folder = sensor_logger(tmp_path / "rec", {"Gyroscope": gyr, "TotalAcceleration": acc})
    log = read_log(folder)
    assert log.six_axis and MAG not in log.streams
    out = tmp_path / "out"
    assert main(["replay", str(folder), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sensors"] == ["gyr", "acc"] and "not observed" in summary["heading"]
    assert (out / "attitude.png").read_bytes()[:4] == b"\x89PNG"
    est = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=2)
    r = so3.quat_to_matrix(est[:, 1:5])
    tilt = np.degrees(np.arccos(np.clip(r[:, 2, 2], -1, 1)))  # body z against up: the phone lies flat
    assert tilt.max() < 1.0
    yaw = np.unwrap(np.arctan2(r[:, 1, 0], r[:, 0, 0]))
    assert yaw[-1] - yaw[0] == pytest.approx(0.5 * (est[-1, 0] - 1.0), abs=0.05)  # the gyro's integral


def test_older_sensor_logger_headers_are_read_by_axis_letter_and_unit(tmp_path):
    _, gyr, acc, mag = motion()
    files = {"Gyroscope": gyr, "TotalAcceleration": acc, "Magnetometer": mag}
    folder = sensor_logger(tmp_path / "old", files, header="old")
    assert detect_format(folder) == "sensorlogger"
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[ACC].xyz[0], acc[0], atol=1e-6)
    np.testing.assert_allclose(log.streams[MAG].xyz[-1], mag[-1], atol=1e-5)


def test_an_export_with_only_the_uncalibrated_files_is_read_and_noted(tmp_path):
    _, gyr, acc, mag = motion()
    files = {"GyroscopeUncalibrated": gyr, "AccelerometerUncalibrated": -acc / 9.80665,  # iOS: g, own axes
             "MagnetometerUncalibrated": mag}  # fmt: skip
    log = read_log(sensor_logger(tmp_path / "raw", files))
    np.testing.assert_allclose(log.streams[ACC].xyz[0], acc[0], atol=1e-5)
    assert sum("Uncalibrated" in n for n in log.notes) >= 3 and any("in g" in n for n in log.notes)


# --------------------------------------------------------------------------- phyphox
HEAD = {
    ACC: (
        "Acceleration x (m/s^2)",
        "Acceleration y (m/s^2)",
        "Acceleration z (m/s^2)",
        "Absolute acceleration (m/s^2)",
    ),
    GYR: ("Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)", "Absolute (rad/s)"),
    MAG: ("Magnetic field x (µT)", "Magnetic field y (µT)", "Magnetic field z (µT)", "Absolute field (µT)"),
}


def phyphox_csv(path: Path, columns: tuple[str, ...], t: np.ndarray, xyz: np.ndarray,
                delimiter: str = ",", decimal: str = ".") -> Path:  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [delimiter.join(f'"{c}"' for c in columns)]
    for ti, row in zip(t, xyz, strict=True):
        values = [ti, *row, *([np.linalg.norm(row)] if len(columns) == 5 else [])]
        lines.append(delimiter.join(f"{v:.9E}".replace(".", decimal) for v in values))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def builtin_export(
    folder: Path,
    kind: SensorKind,
    start_unix_s: float,
    zipped: bool = False,
    delimiter: str = ",",
    decimal: str = ".",
) -> None:
    """A built-in single-sensor experiment's export: Raw Data.csv on its own clock from 0, meta/time.csv
    (event, experiment time, system time, system time text) and meta/device.csv, all in the export's
    dialect (phyphox writes meta/time.csv with the data's separator and decimal mark)."""
    t, gyr, acc, mag = motion(offset=0.0)
    xyz = {ACC: acc, GYR: gyr, MAG: mag}[kind]
    phyphox_csv(folder / "Raw Data.csv", ("Time (s)", *HEAD[kind]), t, xyz, delimiter, decimal)
    (folder / "meta").mkdir()
    rows = [
        ('"event"', '"experiment time"', '"system time"', '"system time text"'),
        ('"START"', "0.000000000E0", f"{start_unix_s:.3f}", '"2024-05-01 10:00:00.000 UTC+02:00"'),
        ('"PAUSE"', f"{t[-1]:.9E}", f"{start_unix_s + t[-1]:.3f}", '"2024-05-01 10:00:04.000 UTC+02:00"'),
    ]
    (folder / "meta" / "time.csv").write_text(
        "".join(delimiter.join(cell.replace(".", decimal) for cell in row) + "\n" for row in rows)
    )
    (folder / "meta" / "device.csv").write_text('"property","value"\n"deviceModel","test"\n')
    if zipped:
        with zipfile.ZipFile(folder.with_suffix(".zip"), "w") as z:
            for f in folder.rglob("*"):
                if f.is_file():
                    z.write(f, f.relative_to(folder).as_posix())
        for f in sorted(folder.rglob("*"), reverse=True):
            f.unlink() if f.is_file() else f.rmdir()
        folder.rmdir()


@pytest.mark.parametrize(
    ("zipped", "delimiter", "decimal"),
    [(False, ",", "."), (True, ",", "."), (True, ";", ","), (False, "\t", ","), (False, ";", ".")],
)
def test_phyphox_builtin_exports_each_on_its_own_clock_are_aligned_by_meta_time(
    tmp_path, zipped, delimiter, decimal
):
    root = tmp_path / "exports"
    dialect = {"zipped": zipped, "delimiter": delimiter, "decimal": decimal}
    builtin_export(root / "Acceleration with g 2024-05-01", ACC, 1_714_550_400.0, **dialect)
    builtin_export(root / "Gyroscope 2024-05-01", GYR, 1_714_550_400.25, **dialect)
    builtin_export(root / "Magnetometer 2024-05-01", MAG, 1_714_550_400.5, **dialect)
    log = read_log(root)
    assert log.format == "phyphox"
    assert log.streams[ACC].t[0] == pytest.approx(0.0)
    assert log.streams[GYR].t[0] == pytest.approx(0.25)
    assert log.streams[MAG].t[0] == pytest.approx(0.5)
    assert any("meta/time.csv" in n for n in log.notes)


def test_phyphox_exports_without_meta_time_cannot_be_aligned_and_say_so(tmp_path):
    root = tmp_path / "exports"
    builtin_export(root / "a", ACC, 1.0)
    builtin_export(root / "g", GYR, 2.0)
    (root / "g" / "meta" / "time.csv").unlink()
    with pytest.raises(InputFormatError, match="meta/time.csv"):
        read_log(root)


def test_phyphox_current_linear_accelerometer_is_ignored_beside_g_and_refused_alone(tmp_path):
    t, gyr, acc, mag = motion()
    folder = tmp_path / "exp"
    phyphox_csv(folder / "Accelerometer.csv", ("Time (s)", *HEAD[ACC][:3]), t, acc)
    phyphox_csv(folder / "Gyroscope.csv", ("Time (s)", *HEAD[GYR][:3]), t, gyr)
    linear = tuple(c.replace("Acceleration", "Linear Acceleration") for c in HEAD[ACC][:3])
    phyphox_csv(folder / "Linear Accelerometer.csv", ("Time (s)", *linear), t, acc - [0, 0, 9.80665])
    log = read_log(folder)
    assert log.six_axis and any("Linear Accelerometer.csv" in n for n in log.notes)
    (folder / "Accelerometer.csv").unlink()
    with pytest.raises(InputFormatError, match="gravity") as info:
        read_log(folder)
    assert "Linear Accelerometer.csv" in info.value.path


@pytest.mark.parametrize("linear_name", ["Linear Accelerometer.csv", "Linear Acceleration.csv"])
def test_phyphox_experiment_with_bare_axis_headers_reads_the_accelerometer_with_g_beside_the_linear_one(
    tmp_path, linear_name
):
    """Current phyphox names an experiment's columns ``"X (m/s^2)"``: the sensor is the file's name. The
    accelerometer with g is read; the linear one beside it is ignored, as docs/formats.md says."""
    t, gyr, acc, mag = motion()
    folder = tmp_path / "experiment"
    bare = {unit: tuple(f"{axis} ({unit})" for axis in "XYZ") for unit in ("m/s^2", "rad/s", "µT")}
    phyphox_csv(folder / "Accelerometer.csv", ("Time (s)", *bare["m/s^2"]), t, acc)
    phyphox_csv(folder / linear_name, ("Time (s)", *bare["m/s^2"]), t, acc - [0, 0, 9.80665])
    phyphox_csv(folder / "Gyroscope.csv", ("Time (s)", *bare["rad/s"]), t, gyr)
    phyphox_csv(folder / "Magnetometer.csv", ("Time (s)", *bare["µT"]), t, mag)
    phyphox_csv(folder / "Barometer.csv", ("Time (s)", "X (hPa)", "Y (hPa)", "Z (hPa)"), t, acc)
    log = read_log(folder)
    assert log.format == "phyphox" and not log.six_axis
    np.testing.assert_allclose(log.streams[ACC].xyz, acc, rtol=1e-8)  # the one with g, not the linear
    np.testing.assert_allclose(log.streams[GYR].xyz, gyr, atol=1e-12)
    np.testing.assert_allclose(log.streams[MAG].xyz, mag, rtol=1e-8)
    assert any(linear_name in n and "gravity removed" in n for n in log.notes)


def test_phyphox_custom_experiment_buffers_without_units(tmp_path):
    t, gyr, acc, mag = motion()
    folder = tmp_path / "custom"
    phyphox_csv(
        folder / "Acceleration.csv", ("time", "Acceleration x", "Acceleration y", "Acceleration z"), t, acc
    )
    phyphox_csv(folder / "Gyroscope.csv", ("time", "Gyroscope x", "Gyroscope y", "Gyroscope z"), t, gyr)
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[ACC].xyz[0], acc[0])
    np.testing.assert_allclose(log.streams[GYR].t, t)


@pytest.mark.parametrize(("delimiter", "decimal"), [("\t", ","), (";", "."), (";", ","), ("\t", ".")])
def test_phyphox_every_csv_option(tmp_path, delimiter, decimal):
    t, gyr, acc, mag = motion()
    folder = tmp_path / "exp"
    for kind, xyz, name in ((ACC, acc, "Accelerometer"), (GYR, gyr, "Gyroscope"), (MAG, mag, "Magnetometer")):
        phyphox_csv(folder / f"{name}.csv", ("Time (s)", *HEAD[kind][:3]), t, xyz, delimiter, decimal)
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[MAG].xyz[-1], mag[-1], rtol=1e-8)


def test_an_excel_export_is_refused_with_a_message_to_export_csv(tmp_path):
    xls = tmp_path / "Acceleration with g 2024-05-01.xls"
    xls.write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504))  # an OLE2 (.xls) header
    for path in (xls, tmp_path):
        with pytest.raises(InputFormatError, match="CSV"):
            read_log(path)
    assert main(["replay", str(xls), "--no-plots", "--out", str(tmp_path / "o")]) == 2


@pytest.mark.parametrize(
    ("lines", "line", "what"),
    [
        (
            ['"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)","Acceleration q (m/s^2)"'],
            1,
            "no z column",
        ),
        (
            ["", '"Time (s)","Acceleration x (furlong)","Acceleration y (m/s^2)","Acceleration z (m/s^2)"'],
            2,
            "unit",
        ),
    ],
)
def test_a_header_with_a_problem_names_its_line(tmp_path, lines, line, what):
    t, gyr, acc, _ = motion(5)
    folder = tmp_path / "exp"
    phyphox_csv(folder / "Gyroscope.csv", ("Time (s)", *HEAD[GYR][:3]), t, gyr)
    body = "\n".join(f"{ti},{x},{y},{z}" for ti, (x, y, z) in zip(t, acc, strict=True))
    (folder / "Accelerometer.csv").write_text("\n".join(lines) + "\n" + body + "\n")
    with pytest.raises(InputFormatError, match=what) as info:
        read_log(folder, format="phyphox")
    assert info.value.line == line and "Accelerometer.csv" in info.value.path


def test_a_6_axis_phyphox_replay_runs_through_the_library(tmp_path):
    t, gyr, acc, _ = motion()
    folder = tmp_path / "exp"
    phyphox_csv(folder / "Accelerometer.csv", ("Time (s)", *HEAD[ACC][:3]), t, acc)
    phyphox_csv(folder / "Gyroscope.csv", ("Time (s)", *HEAD[GYR][:3]), t, gyr)
    result = replay(folder, ReplayOptions(tmp_path / "out"))
    assert result.log.six_axis and len(result.estimates) > 300
    assert any("heading NOT observed" in s for s in result.setup)


# --------------------------------------------------------------------------- the real export, re-laid
REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 1500  # per file: the header and ~30 s of the recording


def real_export(folder: Path, rename=lambda name: name, edit=lambda line: line) -> Path:
    """The first :data:`REAL_LINES` lines of each of the real Sensor Logger export's files, into
    ``folder`` under ``rename(name)``, each line through ``edit``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        with open(REAL / name, encoding="utf-8") as f:
            lines = [edit(next(f).rstrip("\n")) for _ in range(REAL_LINES)]
        (folder / rename(name)).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


def zip_folder(folder: Path, archive: Path, under: str = "", extra: dict[str, bytes] | None = None) -> Path:
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, under + f.relative_to(folder).as_posix())
        for name, data in (extra or {}).items():
            z.writestr(name, data)
    return archive


def semicolons(line: str) -> str:
    """A line as a spreadsheet in a European locale saves it: semicolons, decimal commas."""
    return line.replace(",", ";").replace(".", ",")


def epoch_in(digits_dropped: int):
    """A line whose ``time`` (ns) is cut to µs (3) or ms (6), as a re-export writes it."""

    def edit(line: str) -> str:
        head, _, rest = line.partition(",")
        return line if head == "time" else f"{head[:-digits_dropped]},{rest}"

    return edit


LAYOUTS = {
    "macOS Compress (__MACOSX, ._ files)": lambda tmp: zip_folder(
        real_export(tmp / "Rec"), tmp / "macos.zip", "Rec/",
        {"__MACOSX/Rec/._Gyroscope.csv": b"\x00\x05\x16\x07x", "Rec/.DS_Store": b"\x00\x00\x00\x01Bud1"},
    ),
    "a zip of the export's folder's folder": lambda tmp: zip_folder(
        real_export(tmp / "outer" / "Rec"), tmp / "two.zip", "outer/"
    ),
    "a folder holding the export's zip": lambda tmp: (
        zip_folder(real_export(tmp / "Rec"), (tmp / "holder").mkdir() or tmp / "holder" / "Rec.zip"),
        tmp / "holder",
    )[1],
    "file names in lower case": lambda tmp: real_export(tmp / "lower", rename=str.lower),
    "a semicolon, decimal comma re-save": lambda tmp: real_export(tmp / "semi", edit=semicolons),
}  # fmt: skip


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


@pytest.mark.parametrize("layout", LAYOUTS)
def test_the_real_sensor_logger_export_laid_out_as_users_bring_it_reads_the_same(tmp_path, real_log, layout):
    """Each layout is read as Sensor Logger (never as phyphox: its ns epoch taken for seconds), sample for
    sample as the export itself."""
    path = LAYOUTS[layout](tmp_path)
    assert detect_format(path) == "sensorlogger"
    log = read_log(path)
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(log.streams[kind].t, real_log.streams[kind].t)
        np.testing.assert_array_equal(log.streams[kind].xyz, real_log.streams[kind].xyz)


@pytest.mark.parametrize(("digits", "unit"), [(3, "µs"), (6, "ms")])
def test_an_epoch_in_us_or_ms_is_told_by_its_size_and_noted(tmp_path, real_log, digits, unit):
    log = read_log(real_export(tmp_path / unit, edit=epoch_in(digits)))
    resolution = 10.0 ** (digits - 9)
    for kind in (GYR, ACC, MAG):
        err = np.abs(log.streams[kind].t - real_log.streams[kind].t)
        assert err.max() <= resolution  # the same recording, to the resolution it was cut to
    assert sum(f"'time' in {unit} since the epoch" in n for n in log.notes) == 3
    assert log.end - log.start == pytest.approx(real_log.end - real_log.start, abs=resolution)


def seconds_elapsed_doubled(line: str) -> str:
    time, elapsed, rest = line.split(",", 2)
    return f"{time},{2 * float(elapsed)!r},{rest}"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda line: line if line.startswith("time") else "12345" + line[line.index(","):],
         "no time since the epoch"),
        (lambda line: line if line.startswith("time") else seconds_elapsed_doubled(line), "spans"),
    ],
)  # fmt: skip
def test_a_time_column_that_is_no_epoch_or_disagrees_with_seconds_elapsed_is_a_typed_error(
    tmp_path, edit, message
):
    folder = real_export(tmp_path / "bad", edit=edit)
    with pytest.raises(InputFormatError, match=message) as err:
        read_log(folder)
    assert "Gyroscope.csv" in str(err.value) and "time" in str(err.value)


def test_a_header_only_magnetometer_file_is_a_6_axis_log_and_a_header_only_gyroscope_names_its_file(tmp_path):
    folder = real_export(tmp_path / "rec")
    (folder / "Magnetometer.csv").write_text("time,seconds_elapsed,z,y,x\n")
    log = read_log(folder)
    assert log.six_axis and any("Magnetometer.csv has no samples" in n for n in log.notes)
    (folder / "Gyroscope.csv").write_text("time,seconds_elapsed,z,y,x\n")
    with pytest.raises(InputFormatError, match="no samples") as err:
        read_log(folder)
    assert "Gyroscope.csv" in str(err.value)


def test_a_sensor_whose_rows_are_out_of_time_order_is_warned_about(tmp_path):
    folder = real_export(tmp_path / "rec")
    lines = (folder / "Gyroscope.csv").read_text().splitlines()
    body = lines[1:]
    np.random.default_rng(7).shuffle(body)  # a spreadsheet sorted by another column
    (folder / "Gyroscope.csv").write_text("\n".join([lines[0], *body]) + "\n")
    result = replay(folder, ReplayOptions(out_dir=tmp_path / "out"))
    assert any(w.startswith("gyr:") and "not in time order" in w for w in result.warnings)
    clean = replay(real_export(tmp_path / "clean"), ReplayOptions(out_dir=tmp_path / "out2"))
    assert not any(w.startswith(("gyr:", "acc:", "mag:")) for w in clean.warnings)


def test_a_gunzipped_tyrex_trial_reads_the_calibrated_files_as_the_published_one(tmp_path):
    import gzip
    import shutil

    trial = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Texting"
    plain = tmp_path / trial.name
    plain.mkdir()
    for f in trial.iterdir():
        if f.name.endswith(".gz"):
            with gzip.open(f, "rb") as src, open(plain / f.name.removesuffix(".gz"), "wb") as dst:
                shutil.copyfileobj(src, dst)
        else:
            shutil.copy(f, plain / f.name)
    published, gunzipped = read_log(trial), read_log(plain)
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(gunzipped.streams[kind].xyz, published.streams[kind].xyz)
    assert not any("uncalibrated" in n for n in gunzipped.notes)


def test_a_time_cell_that_is_no_number_is_a_nan_sample_dropped_and_counted_not_a_clock_jump(tmp_path):
    """A ``nan`` (or an overflowing) epoch in one row once became INT64_MIN ns: the whole log moved
    7.5e9 s into the past around a jump the replay split at. It is now that row's NaN sample."""
    folder = real_export(tmp_path / "rec")
    lines = (folder / "Gyroscope.csv").read_text().splitlines()
    lines[500] = "nan" + lines[500][lines[500].index(",") :]
    lines[700] = "1" + "0" * 25 + lines[700][lines[700].index(",") :]
    (folder / "Gyroscope.csv").write_text("\n".join(lines) + "\n")
    result = replay(folder, ReplayOptions(out_dir=tmp_path / "out"))
    assert result.merge_stats.nan["gyr"] == 2 and len(result.segments) == 1
    assert result.estimates.t[0] >= 0.0 and result.estimates.t[-1] < 40.0

"""Sensor Logger exports as other tools leave them, and the app's JSON export (docs/formats.md lists each
layout and its test): every line ending in a trailing delimiter (a re-save), clock columns with their units
in the header, and the JSON export of one array of records — each built here from the real Android export
in ``../shared/data/sensorlogger-android`` (read, never copied into the project) and checked to read sample
for sample as the CSV export itself."""

from __future__ import annotations

import gzip
import json
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from hil.logs.replay import ReplayOptions, replay
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 1500  # per file: the header and ~30 s of the recording
UNITS = {"Gyroscope.csv": "rad/s", "TotalAcceleration.csv": "m/s^2", "Magnetometer.csv": "µT"}

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")


def real_lines(name: str, lines: int = REAL_LINES) -> list[str]:
    """The first ``lines`` lines of one of the real export's files (header first), without line breaks."""
    with open(REAL / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def real_export(folder: Path, edit=lambda name, line: line) -> Path:
    """The first :data:`REAL_LINES` lines of each of the real export's files into ``folder``, each line
    through ``edit(file name, line)``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        lines = [edit(name, line) for line in real_lines(name)]
        (folder / name).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


# --------------------------------------------------------------------------- 1. a trailing delimiter
def semicolons(line: str) -> str:
    """A line as a spreadsheet in a European locale saves it: semicolons, decimal commas."""
    return line.replace(",", ";").replace(".", ",")


@pytest.mark.parametrize("dialect", ["comma", "semicolon, decimal comma", "tab", "CRLF"])
def test_a_trailing_delimiter_on_every_line_is_read_as_the_export(tmp_path, real_log, dialect):
    """``time,seconds_elapsed,z,y,x,`` and every row ``…,1.23,``: the empty last column is no column."""
    edits = {
        "comma": lambda name, line: line + ",",
        "semicolon, decimal comma": lambda name, line: semicolons(line) + ";",
        "tab": lambda name, line: line.replace(",", "\t") + "\t",
        "CRLF": lambda name, line: line + ",\r",
    }
    folder = real_export(tmp_path / "rec", edit=edits[dialect])
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(1, REAL_LINES - 1), value=st.sampled_from(["1.5", "0", "nan", "x", '"7"']))
def test_a_value_in_the_trailing_column_is_read_past_as_any_unused_column(tmp_path, real_log, row, value):
    """The empty last name is a column no reader reads: whatever one row holds there (a number, text,
    a quoted cell) leaves the samples as the export's (docs/formats.md, "Columns a reader does not use")."""
    folder = tmp_path / f"rec{row}"
    real_export(folder, edit=lambda name, line: line + ",")
    gyro = (folder / "Gyroscope.csv").read_text().splitlines()
    gyro[row] += value
    (folder / "Gyroscope.csv").write_text("\n".join(gyro) + "\n")
    assert_same_samples(read_log(folder), real_log)


def test_a_column_with_an_empty_name_in_the_middle_is_read_past(tmp_path, real_log):
    """``time,,seconds_elapsed,…`` with an empty cell on every row: an unnamed column no reader reads."""
    folder = real_export(tmp_path / "rec", edit=lambda name, line: line.replace(",", ",,", 1))
    assert_same_samples(read_log(folder), real_log)


def test_a_trailing_delimiter_is_passed_over_by_the_other_readers_too(tmp_path):
    """The project's own CSV (whose ``w`` cell is empty on sensor rows) and a phyphox file, each
    re-saved with a trailing delimiter, read as they were."""
    from hil.logs.project_csv import write

    log = read_log(real_export(tmp_path / "rec"))
    plain = tmp_path / "log.csv"
    write(log, plain)
    lines = plain.read_text().splitlines()
    trailing = tmp_path / "trailing.csv"
    trailing.write_text("\n".join(x if x.startswith("#") else x + "," for x in lines) + "\n")
    assert detect_format(trailing) == "csv"
    assert_same_samples(read_log(trailing), read_log(plain))

    phyphox = tmp_path / "phyphox"
    phyphox.mkdir()
    heads = {"Accelerometer.csv": "Acceleration", "Gyroscope.csv": "Gyroscope"}
    for name, label in heads.items():
        unit = "m/s^2" if label == "Acceleration" else "rad/s"
        rows = [f'"Time (s)","{label} x ({unit})","{label} y ({unit})","{label} z ({unit})",']
        rows += [f"{0.01 * i:.2f},0.1,0.2,{9.8 if label == 'Acceleration' else 0.3}," for i in range(200)]
        (phyphox / name).write_text("\n".join(rows) + "\n")
    assert detect_format(phyphox) == "phyphox"
    read = read_log(phyphox)
    assert len(read.streams[GYR].t) == 200
    np.testing.assert_allclose(read.streams[GYR].xyz[0], [0.1, 0.2, 0.3])


# --------------------------------------------------------------------------- 2. units on the clocks
def with_units(clock_units: tuple[str, str], brackets: str = "()"):
    """An edit putting units on the header: the clocks' ``clock_units`` and each file's axis unit."""

    def edit(name: str, line: str) -> str:
        if not line.startswith("time"):
            return line
        o, c = brackets
        time_unit, elapsed_unit = clock_units
        axes = [f"{a} {o}{UNITS[name]}{c}" for a in "zyx"]
        return ",".join([f"time {o}{time_unit}{c}", f"seconds_elapsed {o}{elapsed_unit}{c}", *axes])

    return edit


@pytest.mark.parametrize("brackets", ["()", "[]"])
def test_clock_columns_with_units_in_their_header_are_sensor_logger_read_as_the_export(
    tmp_path, real_log, brackets
):
    folder = real_export(tmp_path / "rec", edit=with_units(("ns", "s"), brackets))
    assert detect_format(folder) == "sensorlogger"
    log = read_log(folder)
    assert log.format == "sensorlogger" and any("Sensor Logger" in n for n in log.notes)
    assert_same_samples(log, real_log)


def test_an_axis_unit_in_brackets_is_converted_not_taken_for_si(tmp_path, real_log):
    def degrees(name: str, line: str) -> str:
        if name != "Gyroscope.csv":
            return with_units(("ns", "s"), "[]")(name, line)
        if line.startswith("time"):
            return "time [ns],seconds_elapsed [s],z [deg/s],y [deg/s],x [deg/s]"
        time, elapsed, *xyz = line.split(",")
        return ",".join([time, elapsed, *(repr(float(np.degrees(float(v)))) for v in xyz)])

    log = read_log(real_export(tmp_path / "rec", edit=degrees))
    np.testing.assert_allclose(log.streams[GYR].xyz, real_log.streams[GYR].xyz, rtol=1e-12, atol=1e-15)


def test_a_time_unit_in_the_header_that_its_values_deny_is_an_error_naming_the_column(tmp_path):
    folder = real_export(tmp_path / "rec", edit=with_units(("ms", "s")))
    with pytest.raises(InputFormatError, match="ms") as err:
        read_log(folder)
    assert "Gyroscope.csv" in err.value.path and err.value.column == "time (ms)"


# --------------------------------------------------------------------------- 3. the JSON export
def json_records(lines: int = REAL_LINES, numbers: bool = False) -> list[dict[str, object]]:
    """The first ``lines`` lines of each of the real export's files as the app's JSON export lays them out
    (awesome-sensor-logger, "File Handling → JSON"): one record per row, ``sensor`` the file's name,
    every value a string (``numbers``: as JSON numbers, as a script's re-save writes them), each sensor's
    records together; and a location record, which the reader passes over."""
    records: list[dict[str, object]] = []
    for name in REAL_FILES:
        header, *rows = real_lines(name, lines)
        keys = header.split(",")
        for row in rows:
            values = [json.loads(v) if numbers else v for v in row.split(",")]
            records.append({"sensor": name.removesuffix(".csv"), **dict(zip(keys, values, strict=True))})
    records.append(
        {"sensor": "Location", "time": "1679068248514000000", "seconds_elapsed": "1.3", "speed": "0",
         "latitude": "0.0", "longitude": "0.0"}
    )  # fmt: skip
    return records


def write_json(path: Path, records: list[dict[str, object]], indent: int | None = 2) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(records, indent=indent), encoding="utf-8")
    return path


@pytest.mark.parametrize("layout", ["as documented (indented)", "one line", "numbers, not strings"])
def test_the_json_export_reads_sample_for_sample_as_the_csv_export(tmp_path, real_log, layout):
    records = json_records(numbers=layout.startswith("numbers"))
    path = write_json(tmp_path / "Recording.json", records, None if layout == "one line" else 2)
    assert detect_format(path) == "sensorlogger-json"
    log = read_log(path)
    assert log.format == "sensorlogger-json" and any("Location" in n for n in log.notes)
    assert_same_samples(log, real_log)


def test_replaying_the_json_export_gives_what_replaying_the_csv_export_gives(tmp_path):
    csv_result = replay(real_export(tmp_path / "csv"), ReplayOptions(out_dir=tmp_path / "out_csv"))
    path = write_json(tmp_path / "json" / "Recording.json", json_records())
    json_result = replay(path, ReplayOptions(out_dir=tmp_path / "out_json"))
    assert len(json_result.estimates) == len(csv_result.estimates) > 1000
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(json_result.log.streams[kind].t, csv_result.log.streams[kind].t)
        np.testing.assert_array_equal(json_result.log.streams[kind].xyz, csv_result.log.streams[kind].xyz)
    np.testing.assert_array_equal(json_result.estimates.t, csv_result.estimates.t)
    np.testing.assert_array_equal(json_result.estimates.R, csv_result.estimates.R)


@pytest.mark.parametrize("packing", ["gzipped (.json.gz)", "in the zip the app shares", "in a folder"])
def test_the_json_export_packed_as_users_bring_it_reads_the_same(tmp_path, real_log, packing):
    text = json.dumps(json_records(), indent=2).encode()
    if packing.startswith("gzipped"):
        path = tmp_path / "Recording.json.gz"
        path.write_bytes(gzip.compress(text))
    elif packing.startswith("in the zip"):
        path = tmp_path / "Recording.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("Recording/Recording.json", text)
    else:
        path = tmp_path / "rec"
        path.mkdir()
        (path / "Recording.json").write_bytes(text)
    assert detect_format(path) == "sensorlogger-json"
    assert_same_samples(read_log(path), real_log)


def small_export_text() -> str:
    return json.dumps(json_records(lines=120), indent=2)


FIRST = (
    b'[{"sensor": "Gyroscope", "time": "1679068247609296600", "seconds_elapsed": "0.41", '
    b'"z": "0", "y": "0", "x": "0"},\n'
)
"""A good first record: what follows it gets past detection to the reader."""


def nested(depth: int) -> bytes:
    return FIRST + b'{"sensor": "Gyro", "t": ' + b"[" * depth + b"]" * depth + b"}]"


HOSTILE = {
    "gzip bytes under a .json name": lambda: gzip.compress(small_export_text().encode()),
    "gzip bytes after a good record": lambda: FIRST + gzip.compress(small_export_text().encode()),
    "not an array": lambda: json.dumps(json_records(lines=5)[0]).encode(),
    "an array of arrays, deeply": lambda: FIRST + b"[" * 200_000 + b"]" * 200_000,
    "a record nested 20 000 deep": lambda: nested(20_000),
    "a record nested 60 000 deep": lambda: nested(60_000),
    "a nested value": lambda: b'[{"sensor": "Gyroscope", "time": {"ns": "1"}, "x": "0", "y": "0", "z": "0"}]',
    "one line, one huge record": lambda: FIRST.strip() + b'{"x": "' + b"1" * 5_000_000 + b'"}]',
    "cut short before a sensor's first record": lambda: small_export_text()[:200].encode(),
    "a value that is no number": lambda: small_export_text().replace('"x": "0', '"x": "zero', 1).encode(),
    "a null value": lambda: small_export_text().replace('"y": "', '"y": null, "_": "', 1).encode(),
    "a record with other keys": lambda: small_export_text().replace('"z":', '"w":', 7).encode(),
    "an integer of 10 000 digits": lambda: FIRST + b'{"sensor": "G", "time": ' + b"9" * 10_000 + b"}]",
    "garbage after the array": lambda: (small_export_text() + "\n{}").encode(),
    "binary after a good record": lambda: FIRST + bytes(range(256)) * 100,
    "not UTF-8 after a good record": lambda: FIRST + b'{"sensor": "Gyroscope", "x": "\xff\xfe"}]',
}  # fmt: skip


@pytest.mark.parametrize("case", HOSTILE)
def test_a_hostile_json_file_is_a_typed_error_naming_it(tmp_path, case):
    path = tmp_path / "Recording.json"
    path.write_bytes(HOSTILE[case]())
    with pytest.raises(InputFormatError) as err:
        read_log(path, format="sensorlogger-json")
    assert "Recording.json" in str(err.value)
    with pytest.raises(InputFormatError):  # detected as something or nothing: never a crash
        read_log(path)


def test_a_json_file_past_its_size_bound_is_refused_naming_it_before_it_is_read_whole(tmp_path, monkeypatch):
    from hil.logs import sensorlogger_json

    path = write_json(tmp_path / "Recording.json", json_records())
    monkeypatch.setattr(sensorlogger_json, "MAX_JSON_BYTES", 100_000)
    with pytest.raises(InputFormatError, match="more than 100000 bytes") as err:
        read_log(path)
    assert "Recording.json" in str(err.value)
    bomb = tmp_path / "bomb" / "Recording.json.gz"
    bomb.parent.mkdir()
    bomb.write_bytes(
        gzip.compress(b'[{"sensor": "Gyroscope", "time": "1", "x": "1"}' + b" " * (50 << 20) + b"]")
    )
    monkeypatch.setattr(sensorlogger_json, "MAX_JSON_BYTES", 256 << 20)
    with pytest.raises(InputFormatError, match="compression bomb"):
        read_log(bomb)


def test_reading_the_json_export_holds_the_samples_not_the_file(tmp_path, real_log):
    """A file padded with whitespace (here ~30 times the bytes of the same records) costs what its
    samples do: it is read a piece at a time, never whole."""
    path = write_json(tmp_path / "Recording.json", json_records(), indent=400)
    size = path.stat().st_size
    tracemalloc.start()
    try:
        log = read_log(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert_same_samples(log, real_log)
    assert size > 10e6 and peak < size / 5, (size, peak)


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_any_damage_to_a_json_export_reads_or_is_a_typed_error(tmp_path_factory, data):
    """Cut, spliced or overwritten anywhere, the export reads or fails with InputFormatError; never
    anything else."""
    text = SMALL_EXPORT.encode()
    at = data.draw(st.integers(0, len(text)))
    how = data.draw(st.sampled_from(["cut", "insert", "overwrite"]))
    junk = data.draw(
        st.binary(min_size=1, max_size=8) | st.sampled_from([b"[", b"{", b'"', b"]", b"}", b","])
    )
    damaged = {
        "cut": text[:at],
        "insert": text[:at] + junk + text[at:],
        "overwrite": text[:at] + junk + text[at + len(junk) :],
    }[how]
    path = tmp_path_factory.mktemp("damaged") / "Recording.json"
    path.write_bytes(damaged)
    try:
        read_log(path, format="sensorlogger-json")
    except InputFormatError as exc:
        assert "Recording.json" in str(exc)


SMALL_EXPORT = json.dumps(json_records(lines=80), indent=2) if REAL.is_dir() else "[]"


def test_hil_replay_format_choices_are_the_readers():
    """``--format sensorlogger-json`` was refused by the command line: its choices were a list of their
    own."""
    from hil.cli.replay import FORMATS
    from hil.logs import READERS

    assert sorted(FORMATS) == sorted(READERS)

"""Which column is an axis (docs/formats.md, hil.logs.columns): an exact name (``x``, a sensor's full name
``Gyroscope x (rad/s)``) wins over a partial one (``x accuracy``, ``x_uncalibrated``, ``Linear
Acceleration x (m/s^2)``) wherever it stands; a column saying ``bias`` is never an axis; two columns
equally the axis are an InputFormatError naming the file and both. Before, the first column holding a
lone x was read as x: a decoy before the real one gave silently wrong samples.

And the Sensor Logger JSON export read by the keys it uses only: any other key (unknown, nested, an
array, text, null, 1e308, 10 000 digits, given twice, in any order, in some records only) never stops the
read; an absurd value in a used key is judged exactly as the CSV export's reader judges the same cell
(which no longer lets one ``nan`` time cost the other times of its chunk their exactness).

Built from the real export in ``../shared/data/sensorlogger-android`` (read, never copied)."""

from __future__ import annotations

import json
import random
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
LINES = 120  # per file: the header and ~2 s of the recording
SETTINGS = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

PARTIAL = (
    "{a} accuracy",
    "{A} accuracy",
    "accuracy {a}",
    "{a}_uncalibrated",
    "uncalibrated {a}",
    "{a}-axis",
    "Linear Acceleration {a} (m/s^2)",
    "Rotation {a}",
)
"""Labels holding one lone axis letter that are not the axis's exact name (in any sensor's file)."""
BIAS = ("bias {a}", "{a}bias", "{a}Bias", "{a}_bias", "{a} bias", "bias_{a}", "Bias {A} (rad/s)")
"""Labels of a bias estimate: never an axis."""
DECOY_CELLS = st.sampled_from(["123.5", "-7", "0", "1e3", "42"])
"""A decoy's values: numbers, so that a decoy taken for an axis would give other samples, not an error."""


def real_lines(name: str, lines: int = LINES) -> list[str]:
    with open(REAL / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def write_csv(path: Path, rows: list[list[str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(",".join(row) for row in rows) + "\n", encoding="utf-8")


def sensor_logger(folder: Path, decoys=(), rename=None) -> Path:
    """The real export's first :data:`LINES` lines, ``decoys`` (file, header name, position, cell) added,
    ``rename(file, header)`` applied to each header."""
    for name in REAL_FILES:
        rows = [line.split(",") for line in real_lines(name)]
        if rename is not None:
            rows[0] = rename(name, rows[0])
        for file, header, position, cell in decoys:
            if file == name:
                at = min(position, len(rows[0]))
                for i, row in enumerate(rows):
                    row.insert(at, header if i == 0 else cell)
        write_csv(folder / name, rows)
    return folder


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The plain export's log: what every decoyed copy must read as."""
    return read_log(sensor_logger(tmp_path_factory.mktemp("plain")))


# --------------------------------------------------------------------------- Sensor Logger CSV
@st.composite
def decoys(draw, templates=PARTIAL + BIAS, files=REAL_FILES):
    out = []
    for _ in range(draw(st.integers(1, 4))):
        axis = draw(st.sampled_from("xyz"))
        label = draw(st.sampled_from(templates)).format(a=axis, A=axis.upper())
        out.append((draw(st.sampled_from(files)), label, draw(st.integers(0, 7)), draw(DECOY_CELLS)))
    return out


@SETTINGS
@given(added=decoys())
@example(added=[("Gyroscope.csv", "x accuracy", 0, "123.5")])
@example(added=[("Gyroscope.csv", "Linear Acceleration x (m/s^2)", 2, "42")])
@example(added=[("Magnetometer.csv", "bias z", 1, "-7")])
def test_decoy_columns_before_or_after_the_axes_read_as_the_plain_export(tmp_path_factory, plain, added):
    folder = sensor_logger(tmp_path_factory.mktemp("decoys"), added)
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), plain)


@SETTINGS
@given(spelling=st.sampled_from(BIAS), before=st.booleans(), bias=st.sampled_from(["0.01", "-3", "250"]))
@example(spelling="bias {a}", before=True, bias="250")
def test_an_uncalibrated_gyroscope_is_read_from_its_axes_not_its_bias_columns(
    tmp_path_factory, plain, spelling, before, bias
):
    """GyroscopeUncalibrated.csv (the fallback when there is no Gyroscope.csv) carries the OS's bias
    estimates beside the raw reading: whatever their spelling and place, the reading is read."""
    folder = tmp_path_factory.mktemp("uncal")
    sensor_logger(folder)
    rows = [line.split(",") for line in real_lines("Gyroscope.csv")]
    names = [spelling.format(a=a, A=a.upper()) for a in "zyx"]
    rows = [row[:2] + (names if i == 0 else [bias] * 3) + row[2:] if before else row + (
        names if i == 0 else [bias] * 3) for i, row in enumerate(rows)]  # fmt: skip
    (folder / "Gyroscope.csv").unlink()
    write_csv(folder / "GyroscopeUncalibrated.csv", rows)
    log = read_log(folder)
    assert any("GyroscopeUncalibrated.csv" in n for n in log.notes)
    np.testing.assert_array_equal(log.streams[GYR].xyz, plain.streams[GYR].xyz)


def test_bias_columns_alone_are_no_axes_an_error_naming_the_file(tmp_path):
    folder = sensor_logger(tmp_path / "rec")
    rows = [line.split(",") for line in real_lines("Gyroscope.csv")]
    rows[0] = ["time", "seconds_elapsed", "bias z", "bias y", "bias x"]
    write_csv(folder / "Gyroscope.csv", rows)
    with pytest.raises(InputFormatError, match="no [xyz] column") as err:
        read_log(folder)
    assert "Gyroscope.csv" in str(err.value)


EXACT_TOO = ("X (rad/s)", "x [rad/s]", "Gyroscope x (rad/s)", "GYROSCOPE X", " X ")
"""Names as exact as ``x`` in a gyroscope file: beside the real ``x``, which one is meant cannot be told."""


@SETTINGS
@given(
    exact=st.booleans(),
    first=st.sampled_from(PARTIAL),
    partial=st.sampled_from(PARTIAL),
    exact_too=st.sampled_from(EXACT_TOO),
    position=st.integers(0, 5),
)
@example(exact=False, first="{a} accuracy", partial="{a}_uncalibrated", exact_too="X", position=0)
@example(exact=True, first="{a} accuracy", partial="{a}-axis", exact_too="X (rad/s)", position=0)
def test_two_columns_equally_the_axis_are_an_error_naming_the_file_and_both(
    tmp_path_factory, exact, first, partial, exact_too, position
):
    """Two exact names (``x`` and ``X (rad/s)``), or no exact one and two partial ones (``x accuracy``
    and ``x_uncalibrated``): an InputFormatError naming the file and both columns, never a guess."""
    first, second = first.format(a="x", A="X"), exact_too if exact else partial.format(a="x", A="X")
    if first == second:
        second = "Rotation x" if first != "Rotation x" else "x-axis"
    folder = tmp_path_factory.mktemp("ambiguous")
    sensor_logger(folder, [("Gyroscope.csv", second, position, "1")])
    rows = [line.split(",") for line in (folder / "Gyroscope.csv").read_text().splitlines()]
    if exact:
        both = ("x", second)
    else:  # the real x named in part
        rows[0] = [first if c == "x" else c for c in rows[0]]
        both = (first, second)
    write_csv(folder / "Gyroscope.csv", rows)
    with pytest.raises(InputFormatError, match="two columns could be the x") as err:
        read_log(folder)
    message = str(err.value)
    assert "Gyroscope.csv" in message and all(repr(name.strip()) in message for name in both), message


# --------------------------------------------------------------------------- phyphox
PHYPHOX = {
    "Accelerometer.csv": ("TotalAcceleration.csv", "Acceleration", "m/s^2"),
    "Gyroscope.csv": ("Gyroscope.csv", "Gyroscope", "rad/s"),
    "Magnetometer.csv": ("Magnetometer.csv", "Magnetic field", "µT"),
}


def phyphox(folder: Path, layout: str, decoys=()) -> Path:
    """The real recording as a phyphox experiment's export: ``"Time (s)"`` (its seconds_elapsed), then
    ``"Gyroscope x (rad/s)"``… (``layout="full"``) or current phyphox's ``"X (rad/s)"`` (``"bare"``)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, (source, sensor, unit) in PHYPHOX.items():
        lines = real_lines(source)
        head = lines[0].split(",")
        axes = [f"{sensor} {a} ({unit})" if layout == "full" else f"{a.upper()} ({unit})" for a in "xyz"]
        rows = [["Time (s)", *axes]]
        for line in lines[1:]:
            cells = dict(zip(head, line.split(","), strict=True))
            rows.append([cells["seconds_elapsed"], cells["x"], cells["y"], cells["z"]])
        for file, header, position, cell in decoys:
            if file == name:
                for i, row in enumerate(rows):
                    row.insert(min(position, len(rows[0])), header if i == 0 else cell)
        rows[0] = ['"' + cell + '"' for cell in rows[0]]
        write_csv(folder / name, rows)
    return folder


@pytest.fixture(scope="module")
def plain_phyphox(tmp_path_factory):
    return {layout: read_log(phyphox(tmp_path_factory.mktemp(layout), layout)) for layout in ("full", "bare")}


PHYPHOX_DECOYS = (*PARTIAL, *BIAS, "Absolute acceleration (m/s^2)", "Linear Acceleration {a} (m/s^2)")


@SETTINGS
@given(layout=st.sampled_from(["full", "bare"]), added=decoys(PHYPHOX_DECOYS, tuple(PHYPHOX)))
@example(layout="bare", added=[("Gyroscope.csv", "Linear Acceleration x (m/s^2)", 1, "42")])
@example(layout="full", added=[("Magnetometer.csv", "x accuracy", 0, "123.5")])
def test_phyphox_decoy_columns_read_as_the_plain_export(tmp_path_factory, plain_phyphox, layout, added):
    folder = phyphox(tmp_path_factory.mktemp("phyphox"), layout, added)
    assert detect_format(folder) == "phyphox"
    assert_same_samples(read_log(folder), plain_phyphox[layout])


def test_a_phyphox_file_naming_two_sensors_x_is_an_error_naming_both(tmp_path):
    """``"Acceleration x (m/s^2)"`` before ``"Gyroscope x (rad/s)"``: which sensor the file holds cannot
    be told (its x column says it)."""
    folder = phyphox(tmp_path / "exp", "full", [("Gyroscope.csv", "Acceleration x (m/s^2)", 1, "9.8")])
    with pytest.raises(InputFormatError, match="two columns could be the x") as err:
        read_log(folder)
    message = str(err.value)
    assert "Gyroscope.csv" in message
    assert "'Acceleration x (m/s^2)'" in message and "'Gyroscope x (rad/s)'" in message


# --------------------------------------------------------------------------- Sensor Logger JSON
def json_pairs(lines: int = LINES) -> list[list[tuple[str, object]]]:
    """The real export as the app's JSON export: one record (key, value pairs, every value a string) per
    row, ``sensor`` the file's name."""
    records = []
    for name in REAL_FILES:
        header, *rows = real_lines(name, lines)
        for row in rows:
            records.append(
                [("sensor", name.removesuffix(".csv")), *zip(header.split(","), row.split(","), strict=True)]
            )
    return records


class Raw(str):
    """A JSON value written as is (an integer of 10 000 digits, which json.dumps refuses)."""


def dump(records: list[list[tuple[str, object]]]) -> str:
    def value(v: object) -> str:
        return str(v) if isinstance(v, Raw) else json.dumps(v)

    return (
        "[\n"
        + ",\n".join("{" + ", ".join(f"{json.dumps(k)}: {value(v)}" for k, v in r) + "}" for r in records)
        + "\n]"
    )


EXTRA_KEYS = st.sampled_from(
    ["accuracy", "label", "x accuracy", "xBias", "bias y", "meta", "", "Sensor", "z2"]
)
EXTRA_VALUES = st.sampled_from(
    [{"nested": {"deeper": [1, 2, {"x": "3"}]}}, [1, "two", None], "HIGH", None, 1e308, -1e308, True,
     Raw("9" * 10_000), Raw("1e400"), "", "nan", [], {}]
)  # fmt: skip


@SETTINGS
@given(
    extras=st.lists(st.tuples(EXTRA_KEYS, EXTRA_VALUES), min_size=1, max_size=4),
    twice=st.sampled_from([None, "accuracy", "x", "time"]),
    every=st.integers(1, 7),
    seed=st.integers(0, 2**32),
)
@example(extras=[("accuracy", "HIGH")], twice=None, every=1, seed=0)
def test_json_keys_the_reader_does_not_use_never_stop_the_read(
    tmp_path_factory, plain, extras, twice, every, seed
):
    """Extra keys on every ``every``-th record (unknown, nested, arrays, text, null, 1e308, 10 000
    digits), a key given twice (an unused one with two values, a used one with its own value again),
    every record's keys in a drawn order: the samples of the plain CSV export."""
    records = json_pairs()
    rnd = random.Random(seed)
    for i, record in enumerate(records):
        if i % every == 0:
            record.extend(extras)
        if twice == "accuracy":
            record += [("accuracy", "HIGH"), ("accuracy", {"a": 1})]
        elif twice is not None:
            record.append((twice, dict(record)[twice]))
        rnd.shuffle(record)
    path = tmp_path_factory.mktemp("json") / "Recording.json"
    path.write_text(dump(records), encoding="utf-8")
    assert detect_format(path) == "sensorlogger-json"
    assert_same_samples(read_log(path), plain)


@SETTINGS
@given(left_out=st.sets(st.integers(0, 3 * (LINES - 1) - 1), min_size=1, max_size=40) | st.just("all"))
@example(left_out={5})
def test_json_records_without_seconds_elapsed_read_as_the_export(tmp_path_factory, plain, left_out):
    """``seconds_elapsed`` beside ``time`` may be left out of any record (or all): ``time`` is the clock."""
    records = [
        [(k, v) for k, v in r if not (k == "seconds_elapsed" and (left_out == "all" or i in left_out))]
        for i, r in enumerate(json_pairs())
    ]
    path = tmp_path_factory.mktemp("json") / "Recording.json"
    path.write_text(dump(records), encoding="utf-8")
    assert_same_samples(read_log(path), plain)


@pytest.mark.parametrize(
    "case, column",
    [("x given twice, another value", "x"), ("no x", "x"), ("no time", "time"), ("x nested", "x")],
)
def test_a_used_json_key_missing_twice_or_nested_is_an_error_naming_the_record_and_key(
    tmp_path, case, column
):
    records = json_pairs(lines=30)
    record = records[10]  # a Gyroscope record, on line 12 of the file
    if case.startswith("x given twice"):
        record.append(("x", "5"))
    elif case.startswith("no "):
        record[:] = [(k, v) for k, v in record if k != column]
    else:
        record[:] = [("meta", {"unused": [1]}), *((k, {"v": v} if k == "x" else v) for k, v in record)]
    path = tmp_path / "Recording.json"
    path.write_text(dump(records), encoding="utf-8")
    with pytest.raises(InputFormatError, match="record 11") as err:
        read_log(path)
    assert "Recording.json" in str(err.value) and err.value.line == 12 and err.value.column == column


ABSURD = ["1e160", "-1e160", "-0.0", "NaN", "nan", "inf", "-Infinity", "1e400", "0", "1e30", "-5", "1_0", ""]


@SETTINGS
@given(column=st.sampled_from(["x", "y", "z", "time", "seconds_elapsed"]), value=st.sampled_from(ABSURD),
       row=st.integers(0, LINES - 2), file=st.sampled_from(REAL_FILES))  # fmt: skip
@example(column="time", value="nan", row=5, file="Gyroscope.csv")
@example(column="x", value="1_0", row=3, file="Magnetometer.csv")
def test_an_absurd_used_value_is_judged_alike_in_the_json_and_the_csv_export(
    tmp_path_factory, plain, column, value, row, file
):
    """The same absurd cell in the CSV export and in the JSON export: the same samples and the same noted
    drops, or both an InputFormatError naming the same place; every other row's samples are the plain
    export's (one ``nan`` time once cost its whole chunk of the CSV its times' exactness)."""
    folder = tmp_path_factory.mktemp("csv")
    records = json_pairs()
    sensor_logger(folder)
    rows = [line.split(",") for line in real_lines(file)]
    rows[row + 1][rows[0].index(column)] = value
    write_csv(folder / file, rows)
    at = REAL_FILES.index(file) * (LINES - 1) + row
    records[at] = [(k, value if k == column else v) for k, v in records[at]]
    path = tmp_path_factory.mktemp("json") / "Recording.json"
    path.write_text(dump(records), encoding="utf-8")
    try:
        from_csv = read_log(folder)
    except InputFormatError as exc:
        with pytest.raises(InputFormatError) as err:
            read_log(path)
        assert exc.column == err.value.column and exc.detail in err.value.detail
        if exc.column == column:  # a cell's error (not the clock's, found from all rows): its record
            assert f"record {at + 1}" in str(err.value)
        return
    from_json = read_log(path)
    assert_same_samples(from_json, from_csv)

    def drops(log, where) -> list[str]:
        return [re.sub(r"^.*?: ", "", n.replace(str(where), "")) for n in log.notes if "dropped" in n]

    assert drops(from_json, path) == drops(from_csv, folder)
    kind = {"Gyroscope.csv": GYR, "TotalAcceleration.csv": ACC, "Magnetometer.csv": MAG}[file]
    for k in plain.streams:
        keep = np.arange(len(plain.streams[k].t)) != (row if k is kind else -1)
        np.testing.assert_array_equal(from_csv.streams[k].t[keep], plain.streams[k].t[keep])
        np.testing.assert_array_equal(from_csv.streams[k].xyz[keep], plain.streams[k].xyz[keep])

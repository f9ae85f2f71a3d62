"""Columns a reader does not use, holding anything: an ``accuracy`` of ``HIGH``, an ``activity`` label, a
device name, empty cells, a quoted note with the delimiter in it (docs/formats.md, "Columns a reader does
not use"). Each was an InputFormatError ("'HIGH' is not a number"); now only the columns a reader uses must
hold numbers. The real exports in ``../shared/data`` (read, never copied into the project) get drawn
columns at drawn places and must read sample for sample as they are; a bad cell in a used column, and a
row wider than its header, stay errors naming the file, line and column. A tar export is unpacked once."""

from __future__ import annotations

import csv
import gzip
import tarfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples

from hil.estimation.sensors import SensorKind
from hil.logs import archive, detect_format, read_log
from hil.logs.project_csv import write as write_project_csv
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 300  # per file: the header and ~6 s of the recording
TYREX = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_AR"
TYREX_FILES = ("accelerometer.txt.gz", "gyroscope-calibrated.txt.gz", "magnetometer-calibrated.txt.gz")
SETTINGS = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

# --------------------------------------------------------------------------- drawn columns
HOSTILE = st.one_of(
    st.sampled_from(
        [
            "HIGH",
            "",
            " ",
            "walking",
            "Pixel 7",
            "run #2",
            "a,b;c\td",
            'say "hi"',
            '"',
            "#",
            "nan?",
            "1,5",
            "x",
        ]
    ),
    st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n\x00"), max_size=12),
)
"""A cell of a column no reader uses: text, nothing, the delimiter, quotes, a ``#`` — any line's text."""
NAMES = st.sampled_from(["accuracy", "label", "activity", "device name", "", "Notes (free text)", "accuracy"])
"""The header name of an added column (a name that repeats, an empty one)."""


def csv_cell(text: str, delimiter: str) -> str:
    """``text`` as a CSV writer puts it in a row: quoted (quotes doubled) when it holds the delimiter or a
    quote or begins with a space, as is."""
    if delimiter in text or '"' in text or text[:1].isspace():
        return '"' + text.replace('"', '""') + '"'
    return text


@st.composite
def added_columns(draw, width: int, used_names: tuple[str, ...] = ()):
    """Columns to add to a table of ``width`` columns: (position, header name, cells), the cells cycled
    through the rows; ``used_names`` may repeat as the name of a column added after all of them."""
    columns = []
    for _ in range(draw(st.integers(1, 3))):
        position = draw(st.integers(0, width + len(columns)))
        last = position == width + len(columns)  # after every column there is
        names = NAMES | st.sampled_from(used_names) if used_names and last else NAMES
        columns.append((position, draw(names), draw(st.lists(HOSTILE, min_size=1, max_size=5))))
    return columns


def with_columns(lines: list[str], columns, delimiter: str = ",") -> list[str]:
    """``lines`` (a header, then rows; a line of ``#`` or blank passed over) with ``columns`` added."""
    out = []
    row = 0
    for i, line in enumerate(lines):
        if not line.strip() or line.lstrip().startswith("#"):
            out.append(line)
            continue
        cells = [csv_cell(cell, delimiter) for cell in next(csv.reader([line], delimiter=delimiter))]
        for position, name, texts in columns:
            text = name if i == 0 else texts[row % len(texts)]
            cell = csv_cell(text, delimiter)
            if position == 0 and cell.lstrip().startswith("#"):
                cell = '"' + cell + '"' if not cell.startswith('"') else cell  # not a comment line
            cells.insert(position, cell)
        row += i > 0
        out.append(delimiter.join(cells))
    return out


# --------------------------------------------------------------------------- Sensor Logger
def real_lines(name: str, lines: int = REAL_LINES) -> list[str]:
    with open(REAL / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def real_export(folder: Path, edit=lambda name, lines: lines) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        (folder / name).write_text("\n".join(edit(name, real_lines(name))) + "\n", encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


DIALECTS = {
    "comma": (",", lambda line: line),
    "semicolon, decimal comma": (";", lambda line: line.replace(",", ";").replace(".", ",")),
    "tab": ("\t", lambda line: line.replace(",", "\t")),
}


@SETTINGS
@given(
    columns=added_columns(5, ("time", "seconds_elapsed", "x", "z")),
    dialect=st.sampled_from(sorted(DIALECTS)),
)
@example(columns=[(0, "accuracy", ["\x1e"])], dialect="comma")  # a break to str.splitlines, not to a row
@example(columns=[(5, "note", ["\u2028", "\x85", "\x1c"])], dialect="tab")
@example(columns=[(0, "accuracy", ["HIGH", ""]), (1, "accuracy", ["#"])], dialect="tab")  # "\t#...": a row
def test_columns_of_any_text_beside_the_used_ones_read_sample_for_sample_as_the_export(
    tmp_path_factory, real_log, columns, dialect
):
    """``time,seconds_elapsed,z,y,x`` with columns added before, between and after (a name repeated
    after the column it names: the first is read) read as the export."""
    delimiter, resave = DIALECTS[dialect]

    def edit(name: str, lines: list[str]) -> list[str]:
        return with_columns([resave(line) for line in lines], columns, delimiter)

    folder = real_export(tmp_path_factory.mktemp("extra") / "rec", edit)
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


@SETTINGS
@given(
    columns=added_columns(5),
    data=st.data(),
    bad=st.sampled_from(["HIGH", "", "1.2.3", '"x, y"', "12 m/s", "3 #3"]),
)
def test_a_bad_cell_in_a_used_column_stays_an_error_naming_its_line_and_column(
    tmp_path_factory, columns, data, bad
):
    target = data.draw(st.sampled_from(REAL_FILES))
    row = data.draw(st.integers(1, REAL_LINES - 1))
    column = data.draw(st.sampled_from(["time", "seconds_elapsed", "z", "y", "x"]))

    def edit(name: str, lines: list[str]) -> list[str]:
        if name == target:
            cells = lines[row].split(",")
            cells[("time", "seconds_elapsed", "z", "y", "x").index(column)] = bad
            lines = [*lines[:row], ",".join(cells), *lines[row + 1 :]]
        return with_columns(lines, columns)

    folder = real_export(tmp_path_factory.mktemp("bad") / "rec", edit)
    with pytest.raises(InputFormatError) as err:
        read_log(folder)
    assert err.value.path.endswith(target) and err.value.line == row + 1
    assert err.value.column == column and target in str(err.value)


@SETTINGS
@given(columns=added_columns(5), data=st.data())
def test_a_row_with_a_cell_more_than_its_header_is_an_error_naming_its_line(tmp_path_factory, columns, data):
    """A row one cell wider cannot say which cell is the extra one (a used column could read its
    neighbour's values): an error naming its line, never a row read shifted."""
    row = data.draw(st.integers(1, REAL_LINES - 1))
    extra = data.draw(HOSTILE)

    def edit(name: str, lines: list[str]) -> list[str]:
        lines = with_columns(lines, columns)
        if name == "Gyroscope.csv":
            lines[row] += "," + csv_cell(extra, ",")
        return lines

    folder = real_export(tmp_path_factory.mktemp("wide") / "rec", edit)
    with pytest.raises(InputFormatError, match="values, expected") as err:
        read_log(folder)
    assert err.value.path.endswith("Gyroscope.csv") and err.value.line == row + 1


# --------------------------------------------------------------------------- phyphox
PHYPHOX = {
    "Accelerometer.csv": ("Acceleration", "m/s^2", (0.1, 0.2, 9.8)),
    "Gyroscope.csv": ("Gyroscope", "rad/s", (0.01, -0.02, 0.03)),
    "Magnetometer.csv": ("Magnetic field", "µT", (20.0, 5.0, -40.0)),
}


def phyphox_lines(name: str, rows: int = 200) -> list[str]:
    label, unit, (x, y, z) = PHYPHOX[name]
    head = ['"Time (s)"', *(f'"{label} {axis} ({unit})"' for axis in "xyz")]
    body = [f"{0.01 * i:.2f},{x + 1e-3 * i:.6g},{y - 1e-3 * i:.6g},{z:.6g}" for i in range(rows)]
    return [",".join(head), *body]


def phyphox_export(folder: Path, edit=lambda name, lines: lines) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in PHYPHOX:
        (folder / name).write_text("\n".join(edit(name, phyphox_lines(name))) + "\n", encoding="utf-8")
    return folder


@SETTINGS
@given(columns=added_columns(4))
def test_a_phyphox_export_with_columns_of_any_text_reads_as_the_export(tmp_path_factory, columns):
    plain = read_log(phyphox_export(tmp_path_factory.mktemp("plain") / "exp"))
    folder = phyphox_export(
        tmp_path_factory.mktemp("extra") / "exp", lambda name, lines: with_columns(lines, columns)
    )
    assert detect_format(folder) == "phyphox"
    assert_same_samples(read_log(folder), plain)


def test_phyphox_meta_time_with_a_column_of_text_aligns_the_exports_as_without(tmp_path):
    """Built-in exports side by side, each ``meta/time.csv`` with a device name added: aligned as they
    are without it (only event, experiment time and system time are read)."""

    def exports(root: Path, extra: bool) -> Path:
        for i, name in enumerate(("Accelerometer", "Gyroscope")):
            folder = root / f"{name} {i}"
            folder.mkdir(parents=True)
            (folder / "Raw Data.csv").write_text("\n".join(phyphox_lines(f"{name}.csv")) + "\n")
            (folder / "meta").mkdir()
            rows = [
                '"event","experiment time","system time","system time text"',
                f'"START",0.000000000E0,{1.7e9 + 0.25 * i:.9E},"2023-11-14 22:13:20.{250 * i:03d} UTC+01:00"',
            ]
            if extra:
                rows = [rows[0] + ',"device"', rows[1] + ',"Pixel 7, (phone #2)"']
            (folder / "meta" / "time.csv").write_text("\n".join(rows) + "\n")
        return root

    plain = read_log(exports(tmp_path / "plain", False), format="phyphox")
    log = read_log(exports(tmp_path / "extra", True), format="phyphox")
    assert_same_samples(log, plain)
    assert [n for n in log.notes if "aligned" in n] == [n for n in plain.notes if "aligned" in n]


# --------------------------------------------------------------------------- the project's CSV
def test_the_projects_csv_with_columns_of_any_text_reads_as_without(tmp_path, real_log):
    plain = write_project_csv(real_log, tmp_path / "plain.csv")
    lines = plain.read_text().splitlines()
    columns = [(0, "note", ["HIGH", "", '"a, b"']), (3, "label", ["walk #1", " "]), (8, "x", ["text"])]
    extra = tmp_path / "extra.csv"
    extra.write_text("\n".join(with_columns(lines, columns)) + "\n")
    assert detect_format(extra) == "csv"
    assert_same_samples(read_log(extra), read_log(plain))

    bare = tmp_path / "bare.csv"  # no first line naming the format: the header among others tells it
    bare.write_text(
        "\n".join(line for line in with_columns(lines, columns) if not line.startswith("#")) + "\n"
    )
    assert detect_format(bare) == "csv"
    assert_same_samples(read_log(bare), read_log(plain))


def test_a_bad_cell_in_a_used_column_of_the_projects_csv_names_it_beside_columns_of_text(tmp_path, real_log):
    plain = write_project_csv(real_log, tmp_path / "plain.csv")
    lines = plain.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("t_s,"))
    row = header + 40
    cells = lines[row].split(",")
    cells[1] = "baro"
    lines[row] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(with_columns(lines, [(0, "note", ["HIGH"]), (7, "", ["Pixel 7"])])) + "\n")
    with pytest.raises(InputFormatError, match="unknown sensor 'baro'") as err:
        read_log(bad)
    assert err.value.line == row + 1 and err.value.column == "sensor"


# --------------------------------------------------------------------------- tyrex (no header)
def tyrex_trial(folder: Path, edit=lambda name, lines: lines, rows: int = 300) -> Path:
    """The first ``rows`` lines of the trial's sensor files, through ``edit``, gzipped as published."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in TYREX_FILES:
        with gzip.open(TYREX / name, "rt") as f:
            lines = [next(f).rstrip("\n") for _ in range(rows)]
        (folder / name).write_bytes(gzip.compress(("\n".join(edit(name, lines)) + "\n").encode()))
    return folder


WORD = st.text(st.characters(blacklist_categories=("Cs", "Zs", "Zl", "Zp", "Cc")), min_size=1, max_size=10)
"""A cell of a table split at runs of whitespace: text without any (a cell cannot hold a space there)."""


@pytest.mark.skipif(not TYREX.is_dir(), reason="the shared tyrex trial is not here")
@SETTINGS
@given(words=st.lists(WORD.filter(lambda w: not w.startswith("#")), min_size=1, max_size=4), data=st.data())
def test_a_tyrex_file_with_columns_of_text_after_time_and_xyz_reads_as_the_trial(
    tmp_path_factory, words, data
):
    """Without a header columns are read by position: time, x, y, z; any columns after them are never
    parsed."""
    count = data.draw(st.integers(1, 3))

    def edit(name: str, lines: list[str]) -> list[str]:
        return [
            line + "".join(f" {words[(i + k) % len(words)]}" for k in range(count))
            for i, line in enumerate(lines)
        ]

    plain = read_log(tyrex_trial(tmp_path_factory.mktemp("plain") / "Trial_NoDist_AR"), format="tyrex")
    log = read_log(tyrex_trial(tmp_path_factory.mktemp("extra") / "Trial_NoDist_AR", edit), format="tyrex")
    assert_same_samples(log, plain)


@pytest.mark.skipif(not TYREX.is_dir(), reason="the shared tyrex trial is not here")
def test_a_tyrex_text_column_is_read_past_after_xyz_and_an_error_naming_it_among_them(tmp_path):
    """Without a header the position is the column: text after time, x, y, z is passed over; in front of
    or among them it shifts them, and is named where it stands."""

    def with_text_at(position: int):
        def edit(name: str, lines: list[str]) -> list[str]:
            return [
                " ".join([*line.split()[:position], "walking", *line.split()[position:]]) for line in lines
            ]

        return edit

    assert len(read_log(tyrex_trial(tmp_path / "after" / "T_NoDist_AR", with_text_at(4))).streams[ACC]) == 300
    for position in (0, 2):
        trial = tyrex_trial(tmp_path / f"at{position}" / "T_NoDist_AR", with_text_at(position))
        with pytest.raises(InputFormatError, match="'walking' is not a number") as err:
            read_log(trial, format="tyrex")
        assert err.value.line == 1 and err.value.column == f"col{position}"
        assert "accelerometer.txt.gz" in err.value.path


# --------------------------------------------------------------------------- a tar, unpacked once
def test_a_tar_export_is_unpacked_once_to_detect_and_read_it(tmp_path, real_log, monkeypatch):
    """Detecting the format and reading the log open one container: the tar is read from its start once
    (it was twice: once to detect, once to read)."""
    folder = real_export(
        tmp_path / "rec", lambda name, lines: with_columns(lines, [(5, "accuracy", ["HIGH"])])
    )
    packed = tmp_path / "rec.tar.gz"
    with tarfile.open(packed, "w:gz") as tar:
        for f in sorted(folder.iterdir()):
            tar.add(f, f"Rec/{f.name}")
    opened = []
    real_open = archive.tarfile.open

    def counting_open(*args, **kwargs):
        opened.append(kwargs.get("mode"))
        return real_open(*args, **kwargs)

    monkeypatch.setattr(archive.tarfile, "open", counting_open)
    assert_same_samples(read_log(packed), real_log)
    assert len(opened) == 1

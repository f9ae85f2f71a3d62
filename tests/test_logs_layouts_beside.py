"""The real Sensor Logger export laid out as another phone, app version or user lays it out, beside the
paths the other layout tests walk (docs/formats.md, "Layouts read"): digits that are not ASCII, a JSON
clock key that appears late, a header name holding a delimiter, a time in s with a fraction or as an
ISO-8601 date, a comment before the header, the header repeated mid-file, UTF-16 without a byte-order
mark, a zip gzipped, a zip of two recordings, a file on another clock, and containers closed when read.
Each variant is built here from ``../shared/data`` (read, never copied into the project) and must read
sample for sample as the export (within the resolution its layout keeps), or end in one
:class:`InputFormatError` naming the file (and line and column where there is one)."""

from __future__ import annotations

import datetime
import gzip
import json
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples

from hil.cli import main
from hil.logs import archive, detect_format, read_log, table
from hil.logs.table import Container
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 300  # per file: the header and ~6 s of the recording

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")


def real_lines(name: str, lines: int = REAL_LINES) -> list[str]:
    """The first ``lines`` lines of one of the real export's files (header first), without line breaks."""
    with open(REAL / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def real_export(folder: Path, edit=lambda name, lines: lines, encode=lambda text: text.encode()) -> Path:
    """The first :data:`REAL_LINES` lines of each real file into ``folder``, through ``edit(name, lines)``
    and ``encode(text)``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        (folder / name).write_bytes(encode("\n".join(edit(name, real_lines(name))) + "\n"))
    return folder


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


def with_time(convert):
    """An edit putting ``convert(ns)`` in each row's ``time`` (the first column)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        out = lines[:1]
        for line in lines[1:]:
            cells = line.split(",")
            cells[0] = convert(int(cells[0]))
            out.append(",".join(cells))
        return out

    return edit


def assert_times_close(log, reference, atol: float) -> None:
    """The same streams and readings, the times within ``atol`` s (a layout that keeps less than ns)."""
    assert set(log.streams) == set(reference.streams)
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz)
        np.testing.assert_allclose(log.streams[kind].t, stream.t, rtol=0, atol=atol)


# --------------------------------------------------------------------------- 1. digits that are not ASCII
NON_ASCII_NUMBERS = ["١٢", "１２", "۱۲.۵", "-٠.٥", "٣"]  # Arabic-Indic, fullwidth, Persian digits


@pytest.mark.parametrize("cell", NON_ASCII_NUMBERS)
def test_a_cell_of_digits_that_are_not_ascii_is_not_a_number_in_the_csv_export(tmp_path, cell):
    """Python's float() reads "١٢" as 12; NumPy, a spreadsheet and the app do not: an error naming it."""

    def edit(name, lines):
        if name == "Gyroscope.csv":
            cells = lines[9].split(",")
            cells[4] = cell  # x
            lines[9] = ",".join(cells)
        return lines

    with pytest.raises(InputFormatError, match="not a number") as err:
        read_log(real_export(tmp_path / "e", edit))
    assert err.value.path.endswith("Gyroscope.csv") and err.value.line == 10 and err.value.column == "x"


@pytest.mark.parametrize("cell", NON_ASCII_NUMBERS)
@pytest.mark.parametrize("column", ["x", "w"])
def test_a_cell_of_digits_that_are_not_ascii_is_not_a_number_in_the_projects_csv(tmp_path, cell, column):
    rows = ["t_s,sensor,x,y,z,w"]
    rows += [f"{i * 0.01:.2f},gyr,0.1,0.2,0.3," for i in range(5)]
    rows += [f"{i * 0.01:.2f},acc,0.1,0.2,9.8," for i in range(5)]
    cells = rows[3].split(",")
    cells[2 if column == "x" else 5] = cell
    rows[3] = ",".join(cells)
    path = tmp_path / "log.csv"
    path.write_text("# vscmg-hil sensor log v1\n" + "\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(InputFormatError, match="not a number") as err:
        read_log(path)
    assert err.value.line == 5 and err.value.column == column  # the comment, the header, 2 rows


def json_records(lines: int = REAL_LINES) -> list[dict[str, object]]:
    """The real export's first ``lines`` lines of each file as the app's JSON export's records (every
    value a string, each sensor's records together)."""
    records: list[dict[str, object]] = []
    for name in REAL_FILES:
        header, *rows = real_lines(name, lines)
        keys = header.split(",")
        for row in rows:
            records.append(
                {"sensor": name.removesuffix(".csv"), **dict(zip(keys, row.split(","), strict=True))}
            )
    return records


def write_json(path: Path, records: list[dict[str, object]]) -> Path:
    path.write_text(json.dumps(records, indent=2), encoding="utf-8")
    return path


@pytest.mark.parametrize("cell", NON_ASCII_NUMBERS)
def test_a_value_of_digits_that_are_not_ascii_is_not_a_number_in_the_json_export(tmp_path, cell):
    records = json_records()
    records[7]["y"] = cell
    with pytest.raises(InputFormatError, match="not a number") as err:
        read_log(write_json(tmp_path / "Recording.json", records))
    assert "record 8" in str(err.value) and err.value.column == "y"


# ------------------------------------------------------------------ 2. a JSON clock key that appears late
def without_key_in_first_records(key: str) -> list[dict[str, object]]:
    """The real export's JSON records, ``key`` left out of each sensor's first record."""
    records = json_records()
    first: set[object] = set()
    for record in records:
        if record["sensor"] not in first:
            first.add(record["sensor"])
            del record[key]
    return records


def test_a_json_time_key_first_given_after_a_sensors_first_record_is_read_not_ignored(tmp_path, real_log):
    """Each sensor's first record lacks ``time`` (it has ``seconds_elapsed``); the others have both. The
    recording's clock is ``time`` from the record that first gives it: the rows before it are NaN samples,
    noted — never the whole sensor read on the other clock with ``time`` passed over."""
    records = without_key_in_first_records("time")
    log = read_log(write_json(tmp_path / "Recording.json", records))
    assert any("time: ns since epoch" in note for note in log.notes)
    assert sum("no time of this recording" in note for note in log.notes) == 3
    for kind, stream in real_log.streams.items():
        got = log.streams[kind]
        assert np.all(np.isnan(got.xyz[0]))  # the record without a time: a NaN sample, dropped by the merge
        np.testing.assert_array_equal(got.xyz[1:], stream.xyz[1:])
        # the same epoch times, on an origin the first records no longer set
        np.testing.assert_allclose(np.diff(got.t[1:]), np.diff(stream.t[1:]), rtol=0, atol=1e-12)
    origin = min(s.t[1] for s in real_log.streams.values())
    for kind, stream in real_log.streams.items():
        np.testing.assert_allclose(log.streams[kind].t[1:], stream.t[1:] - origin, rtol=0, atol=1e-9)


def test_a_json_seconds_elapsed_key_first_given_later_is_read_beside_time(tmp_path, real_log):
    records = without_key_in_first_records("seconds_elapsed")
    assert_same_samples(read_log(write_json(tmp_path / "Recording.json", records)), real_log)


def test_a_json_time_key_given_late_on_another_clock_is_not_passed_over(tmp_path):
    """The late ``time`` is read, so a file whose ``time`` disagrees with its ``seconds_elapsed`` is told."""
    records = without_key_in_first_records("time")
    for record in records:
        if record["sensor"] == "Magnetometer" and "time" in record:
            record["time"] = str(int(str(record["time"])) - 3_000_000_000_000)
    with pytest.raises(InputFormatError, match="another clock") as err:
        read_log(write_json(tmp_path / "Recording.json", records))
    assert err.value.column == "time"


# --------------------------------------------------------------------------- 3. the dialect sniffer
HEADER_NAMES = ["note; free text", "note\tfree", '"note; quoted"', '"a\tb"', "x;y;z label"]


@pytest.mark.parametrize("name", HEADER_NAMES)
def test_a_header_name_holding_a_semicolon_or_a_tab_does_not_change_the_delimiter(tmp_path, real_log, name):
    def edit(_, lines):
        return [lines[0] + "," + name] + [line + ",walk" for line in lines[1:]]

    assert_same_samples(read_log(real_export(tmp_path / "e", edit)), real_log)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    delimiter=st.sampled_from([",", ";", "\t"]),
    others=st.lists(st.sampled_from([",", ";", "\t", " "]), min_size=1, max_size=3),
    at=st.integers(0, 5),
)
def test_any_delimiter_inside_a_quoted_header_name_leaves_the_dialect(
    tmp_path_factory, real_log, delimiter, others, at
):
    """A quoted header name may hold any delimiter, in a file of any of them (with decimal commas beside
    ``;`` and tab, as a European re-save writes): the file reads as the export."""
    label = '"n' + "".join(others) + 'x"'

    def edit(_, lines):
        header = lines[0].split(",")
        header.insert(at, label)
        out = [delimiter.join(header)]
        for line in lines[1:]:
            cells = line.split(",")
            if delimiter != ",":
                cells = [c.replace(".", ",") for c in cells]
            cells.insert(at, "walk")
            out.append(delimiter.join(cells))
        return out

    folder = real_export(tmp_path_factory.mktemp("sniff") / "e", edit)
    assert_same_samples(read_log(folder), real_log)


# --------------------------------------------------------------------------- 4. containers closed
def test_a_container_is_a_context_manager_that_closes_what_it_spooled(tmp_path, monkeypatch):
    export = real_export(tmp_path / "Rec")
    tar = tmp_path / "Rec.tar.gz"
    with tarfile.open(tar, "w:gz") as t:
        t.add(export, arcname="Rec")
    spooled = []
    real_temporary_file = archive.tempfile.TemporaryFile

    def recording(*args, **kwargs):
        f = real_temporary_file(*args, **kwargs)
        spooled.append(f)
        return f

    monkeypatch.setattr(archive.tempfile, "TemporaryFile", recording)
    log = read_log(tar)  # read_log closes its container
    assert len(log.streams) == 3 and spooled and all(f.closed for f in spooled)
    spooled.clear()
    with Container(tar) as c:
        assert "Gyroscope.csv" in c.names()
        assert spooled and not any(f.closed for f in spooled)
    assert all(f.closed for f in spooled)
    c.close()  # idempotent
    assert detect_format(tar) == "sensorlogger" and all(f.closed for f in spooled)


def test_a_container_whose_archive_is_damaged_closes_what_it_opened(tmp_path, monkeypatch):
    export = real_export(tmp_path / "Rec")
    inner = tmp_path / "inner.zip"
    with zipfile.ZipFile(inner, "w") as z:
        for name in REAL_FILES:
            z.write(export / name, f"Rec/{name}")
    outer = tmp_path / "outer.tar"
    with tarfile.open(outer, "w") as t:
        t.add(inner, arcname="inner.zip")
    data = bytearray(outer.read_bytes())
    data[-3000:] = b"\x00" * 3000  # the tar cut short: its last blocks gone
    outer.write_bytes(bytes(data[: len(data) // 2]))
    spooled = []
    real_temporary_file = archive.tempfile.TemporaryFile
    monkeypatch.setattr(
        archive.tempfile,
        "TemporaryFile",
        lambda *a, **k: spooled.append(real_temporary_file(*a, **k)) or spooled[-1],
    )
    with pytest.raises(InputFormatError):
        read_log(outer)
    assert all(f.closed for f in spooled)


# --------------------------------------------------------------------------- 5. clocks laid out otherwise
@pytest.mark.parametrize(
    ("unit", "convert", "atol"),
    [
        ("s, 9 decimals", lambda ns: f"{ns / 1e9:.9f}", 1e-6),
        ("s, 3 decimals", lambda ns: f"{ns / 1e9:.3f}", 1e-3),
        ("ms, 6 decimals", lambda ns: f"{ns / 1e6:.6f}", 1e-6),
        ("ms, whole", lambda ns: str(ns // 10**6), 1e-3),
        ("µs, 3 decimals", lambda ns: f"{ns / 1e3:.3f}", 1e-6),
        ("µs, whole", lambda ns: str(ns // 10**3), 1e-6),
    ],
)
def test_an_epoch_time_in_s_ms_or_us_with_a_fraction_keeps_its_fraction(
    tmp_path, real_log, unit, convert, atol
):
    """``1679068247.609`` (s) was cut to the whole second: 50 gyroscope samples on one time, 49 of them
    dropped as duplicates by the merge."""
    log = read_log(real_export(tmp_path / "e", with_time(convert)))
    assert_times_close(log, real_log, atol)
    assert len(np.unique(log.streams[next(iter(log.streams))].t)) == REAL_LINES - 1


def iso(ns: int, sep: str = "T", zone: str = "Z", digits: int = 9, offset_h: int = 0) -> str:
    seconds, fraction = divmod(ns, 10**9)
    when = datetime.datetime.fromtimestamp(seconds, datetime.timezone(datetime.timedelta(hours=offset_h)))
    text = when.strftime(f"%Y-%m-%d{sep}%H:%M:%S")
    if digits:
        text += "." + f"{fraction:09d}"[:digits]
    return text + zone


@pytest.mark.parametrize(
    ("layout", "convert", "atol"),
    [
        ("ns, Z", lambda ns: iso(ns), 1e-6),
        ("µs, +00:00", lambda ns: iso(ns, zone="+00:00", digits=6), 2e-6),
        ("µs, no zone, a space", lambda ns: iso(ns, sep=" ", zone="", digits=6), 2e-6),
        ("ms, +02:00", lambda ns: iso(ns, zone="+02:00", digits=3, offset_h=2), 2e-3),
    ],
)
def test_an_iso_8601_time_is_read_as_the_epoch_it_names(tmp_path, real_log, layout, convert, atol):
    folder = real_export(tmp_path / "e", with_time(convert))
    assert detect_format(folder) == "sensorlogger"
    assert_times_close(read_log(folder), real_log, atol)


def test_an_iso_time_among_numbers_or_a_date_that_is_none_is_an_error_naming_its_line(tmp_path):
    def edit(name, lines):
        lines = with_time(iso)(name, lines)
        if name == "Gyroscope.csv":
            lines[20] = "2023-02-30T10:00:00Z" + lines[20][lines[20].index(",") :]
        return lines

    with pytest.raises(InputFormatError, match="ISO-8601") as err:
        read_log(real_export(tmp_path / "e", edit))
    assert err.value.path.endswith("Gyroscope.csv") and err.value.line == 21 and err.value.column == "time"


@pytest.mark.parametrize("shift_s", [3000.0, 5.0])
def test_a_sensor_file_on_another_clock_base_is_an_error_naming_it(tmp_path, shift_s):
    """The magnetometer's ``time`` shifted (another recording's file put beside, a tool's edit): its
    ``time`` less ``seconds_elapsed`` differs from the other files'. Read, its samples would lie 3000 s
    (or 5 s) from the gyroscope's taken at the same moment."""

    def edit(name, lines):
        if name != "Magnetometer.csv":
            return lines
        return with_time(lambda ns: str(ns - int(shift_s * 1e9)))(name, lines)

    with pytest.raises(InputFormatError, match="another clock") as err:
        read_log(real_export(tmp_path / "e", edit))
    assert err.value.path.endswith("Magnetometer.csv") and err.value.column == "time"


def test_files_without_seconds_elapsed_whose_spans_lie_apart_are_an_error(tmp_path):
    def edit(name, lines):
        lines = [",".join(c for i, c in enumerate(line.split(",")) if i != 1) for line in lines]
        if name == "Magnetometer.csv":
            lines = with_time(lambda ns: str(ns + 3_000 * 10**9))(name, lines)
        return lines

    with pytest.raises(InputFormatError, match="not on one clock"):
        read_log(real_export(tmp_path / "e", edit))


# --------------------------------------------------------------------------- 6. files laid out otherwise
def test_a_comment_line_before_the_header_is_read_past(tmp_path, real_log):
    folder = real_export(tmp_path / "e", lambda name, lines: ["# exported by a tool", "", *lines])
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


@pytest.mark.parametrize("quote", [False, True])
def test_the_header_repeated_mid_file_is_read_past_and_noted(tmp_path, real_log, quote):
    """Exports joined one after another (``cat a.csv b.csv``): the second header is passed over, noted."""

    def edit(_, lines):
        header = ",".join(f'"{c}"' for c in lines[0].split(",")) if quote else lines[0]
        return [lines[0], *lines[1:100], header, *lines[100:]]

    log = read_log(real_export(tmp_path / "e", edit))
    assert_same_samples(log, real_log)
    assert sum("header repeated on 1 line(s) (101)" in note for note in log.notes) == 3


def test_the_header_repeated_in_the_projects_csv_and_phyphox_is_read_past_too(tmp_path):
    rows = ["t_s,sensor,x,y,z,w"] + [f"{i * 0.01:.2f},gyr,0.1,0.2,0.3," for i in range(5)]
    rows += [f"{i * 0.01:.2f},acc,0.1,0.2,9.8," for i in range(5)]
    path = tmp_path / "log.csv"
    path.write_text("\n".join([*rows[:6], rows[0], *rows[6:]]) + "\n", encoding="utf-8")
    log = read_log(path)
    assert len(log.streams[next(iter(log.streams))].t) == 5 and any("header repeated" in n for n in log.notes)
    folder = tmp_path / "phyphox"
    folder.mkdir()
    for name, label, values in (
        ("Accelerometer.csv", "Acceleration", "0.1,0.2,9.8"),
        ("Gyroscope.csv", "Gyroscope", "0.01,0.02,0.03"),
    ):
        unit = "m/s^2" if label == "Acceleration" else "rad/s"
        header = f'"Time (s)","{label} x ({unit})","{label} y ({unit})","{label} z ({unit})"'
        lines = [header] + [f"{i * 0.01:.2f},{values}" for i in range(6)]
        (folder / name).write_text("\n".join([*lines[:3], header, *lines[3:]]) + "\n", encoding="utf-8")
    log = read_log(folder)
    assert log.format == "phyphox" and all(len(s.t) == 6 for s in log.streams.values())
    assert any("header repeated" in n for n in log.notes)


@pytest.mark.parametrize("order", ["le", "be"])
def test_utf16_without_a_byte_order_mark_reads_as_the_export(tmp_path, real_log, order):
    folder = real_export(tmp_path / "e", encode=lambda text: text.encode(f"utf-16-{order}"))
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


# --------------------------------------------------------------------------- 7. archives laid out otherwise
def zipped(path: Path, entries: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in entries.items():
            z.writestr(name, data)
    return path


@pytest.mark.parametrize("name", ["Recording.zip.gz", "Recording.gz", "Recording.zip"])
def test_a_zip_gzipped_reads_as_the_zip(tmp_path, real_log, name):
    export = real_export(tmp_path / "e")
    plain = zipped(tmp_path / "plain.zip", {f"Rec/{n}": (export / n).read_bytes() for n in REAL_FILES})
    path = tmp_path / name
    path.write_bytes(gzip.compress(plain.read_bytes()))
    assert detect_format(path) == "sensorlogger"
    assert_same_samples(read_log(path), real_log)


def test_a_zip_gzipped_inside_a_folder_reads_as_the_export(tmp_path, real_log):
    export = real_export(tmp_path / "e")
    plain = zipped(tmp_path / "plain.zip", {n: (export / n).read_bytes() for n in REAL_FILES})
    folder = tmp_path / "mail"
    folder.mkdir()
    (folder / "Recording.zip.gz").write_bytes(gzip.compress(plain.read_bytes()))
    assert_same_samples(read_log(folder), real_log)


@pytest.mark.parametrize("layout", ["two folders", "one at the top, one in a folder", "zips side by side"])
def test_a_zip_of_two_recordings_is_refused_naming_both_never_one_read_silently(tmp_path, layout):
    export = real_export(tmp_path / "e")
    files = {n: (export / n).read_bytes() for n in REAL_FILES}
    if layout == "two folders":
        entries = {f"{r}/{n}": data for r in ("Rec1", "Rec2") for n, data in files.items()}
    elif layout == "one at the top, one in a folder":
        entries = {**files, **{f"Rec2/{n}": data for n, data in files.items()}}
    else:
        inner = zipped(tmp_path / "inner.zip", files).read_bytes()
        entries = {"Rec1.zip": inner, "Rec2.zip": inner}
    path = zipped(tmp_path / "both.zip", entries)
    with pytest.raises(InputFormatError, match="several folders") as err:
        read_log(path)
    assert "Rec2" in str(err.value) and err.value.path == str(path)


# --------------------------------------------------------------------------- 8. many layouts at once
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    order=st.permutations(range(5)),
    extra=st.lists(st.sampled_from(["accuracy", "label", "", "note (m/s^2)"]), max_size=2, unique=True),
    delimiter=st.sampled_from([",", ";", "\t"]),
    case=st.sampled_from([str, str.upper, str.title, lambda s: f" {s} "]),
    quote=st.booleans(),
    newline=st.sampled_from(["\n", "\r\n"]),
    encoding=st.sampled_from(["utf-8", "utf-8-sig", "utf-16"]),
)
def test_any_column_order_extra_columns_dialect_case_quoting_and_encoding_reads_as_the_export(
    tmp_path_factory, real_log, order, extra, delimiter, case, quote, newline, encoding
):
    def edit(_, lines):
        out = []
        for i, line in enumerate(lines):
            cells = [line.split(",")[j] for j in order]
            if i == 0:
                cells = [case(c) for c in cells] + list(extra)
            else:
                if delimiter != ",":
                    cells = [c.replace(".", ",") for c in cells]
                cells += ["HIGH" if e else "" for e in extra]
            if quote:
                cells = [f'"{c}"' for c in cells]
            out.append(delimiter.join(cells))
        return out

    folder = tmp_path_factory.mktemp("layout") / "e"
    folder.mkdir()
    for name in REAL_FILES:
        text = newline.join(edit(name, real_lines(name))) + newline
        (folder / name).write_bytes(text.encode(encoding))
    assert_same_samples(read_log(folder), real_log)


# --------------------------------------------------------------------------- 9. through `hil replay`
def test_hil_replay_of_a_zip_of_two_recordings_exits_2_saying_so(tmp_path, capsys):
    export = real_export(tmp_path / "e")
    path = zipped(
        tmp_path / "both.zip", {f"{r}/{n}": (export / n).read_bytes() for r in ("A", "B") for n in REAL_FILES}
    )
    assert main(["replay", str(path), "--out", str(tmp_path / "o"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "both.zip" in err and "several folders" in err


def test_hil_replay_of_a_gzipped_zip_with_iso_times_replays(tmp_path):
    export = real_export(tmp_path / "e", with_time(iso))
    plain = zipped(tmp_path / "plain.zip", {n: (export / n).read_bytes() for n in REAL_FILES})
    path = tmp_path / "Recording.zip.gz"
    path.write_bytes(gzip.compress(plain.read_bytes()))
    out = tmp_path / "o"
    assert main(["replay", str(path), "--out", str(out), "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["merge"]["accepted"]["gyr"] == REAL_LINES - 1


# --------------------------------------------------------------------------- 10. a spreadsheet's rounded time
@pytest.mark.parametrize("rounded", ["1.67907E+18", "whole seconds"])
def test_a_time_a_spreadsheet_rounded_is_read_by_seconds_elapsed_and_noted(tmp_path, real_log, rounded):
    """Excel re-saves ``1679068247609296600`` as it shows it, ``1.67907E+18``: every sample one time. The
    export's ``seconds_elapsed`` (s since the recording started, the same clock) is read instead."""
    convert = (lambda ns: f"{ns:.5E}") if rounded.startswith("1.") else (lambda ns: str(ns // 10**9))
    log = read_log(real_export(tmp_path / "e", with_time(convert)))
    assert sum("'time' takes" in note for note in log.notes) == 1
    assert "time: seconds_elapsed (the epoch 'time' rounded)" in log.notes
    origin = min(s.t[0] for s in log.streams.values()) - min(s.t[0] for s in real_log.streams.values())
    for kind, stream in real_log.streams.items():
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz)
        np.testing.assert_allclose(log.streams[kind].t - origin, stream.t, rtol=0, atol=1e-6)


def test_an_export_read_again_by_seconds_elapsed_counts_its_rows_once_towards_the_limit(
    tmp_path, real_log, monkeypatch
):
    """The files of an export whose ``time`` is rounded are read twice (by ``time``, then by
    ``seconds_elapsed``); their rows count once towards the log's limit, so an export under it reads."""
    rows = 3 * (REAL_LINES - 1)
    monkeypatch.setattr(table, "MAX_LOG_SAMPLES", rows)
    log = read_log(real_export(tmp_path / "e", with_time(lambda ns: f"{ns:.5E}")))
    assert sum(len(s.t) for s in log.streams.values()) == rows
    monkeypatch.setattr(table, "MAX_LOG_SAMPLES", rows - 1)
    with pytest.raises(InputFormatError, match="more than"):
        read_log(real_export(tmp_path / "f", with_time(lambda ns: f"{ns:.5E}")))


def test_a_rounded_time_without_seconds_elapsed_is_an_error_naming_the_column(tmp_path):
    def edit(name, lines):
        lines = [",".join(c for i, c in enumerate(line.split(",")) if i != 1) for line in lines]
        return with_time(lambda ns: f"{ns:.5E}")(name, lines)

    with pytest.raises(InputFormatError, match="rounded") as err:
        read_log(real_export(tmp_path / "e", edit))
    assert err.value.column == "time" and err.value.path.endswith(".csv")


def test_an_iso_8601_time_in_the_json_export_is_read_as_the_csv_export_reads_it(tmp_path, real_log):
    records = [{**r, "time": iso(int(str(r["time"])))} for r in json_records()]
    assert_times_close(read_log(write_json(tmp_path / "Recording.json", records)), real_log, 1e-6)
    records[5]["time"] = "2023-13-01T00:00:00Z"
    with pytest.raises(InputFormatError, match="not a number") as err:
        read_log(write_json(tmp_path / "Bad.json", records))
    assert "record 6" in str(err.value) and err.value.column == "time"


def test_a_json_file_that_is_not_the_export_says_what_the_export_is(tmp_path):
    path = tmp_path / "Recording.json"
    path.write_text("\n".join(json.dumps(r) for r in json_records(20)), encoding="utf-8")  # JSON Lines
    with pytest.raises(InputFormatError, match="one array of records"):
        read_log(path)


def test_a_tar_of_two_recordings_is_refused_and_a_metadata_file_beside_one_is_not_a_second(
    tmp_path, real_log
):
    export = real_export(tmp_path / "e")
    both = tmp_path / "both"
    for r in ("Rec1", "Rec2"):
        (both / r).mkdir(parents=True)
        for n in REAL_FILES:
            (both / r / n).write_bytes((export / n).read_bytes())
    tar = tmp_path / "both.tgz"
    with tarfile.open(tar, "w:gz") as t:
        t.add(both, arcname="both")
    with pytest.raises(InputFormatError, match="several folders"):
        read_log(tar)
    entries = {f"Rec/{n}": (export / n).read_bytes() for n in REAL_FILES}
    entries["Metadata.csv"] = b"platform,appVersion\nandroid,1.0\n"  # beside the folder: no second recording
    assert_same_samples(read_log(zipped(tmp_path / "one.zip", entries)), real_log)


@pytest.mark.parametrize(
    ("head", "dialect"),
    [
        (["time,seconds_elapsed,z,y,x,note;a", "1,2,3,4,5,walk"], (",", False)),
        (["time,seconds_elapsed,z,y,x,note\ta", "1,2,3,4,5,walk"], (",", False)),
        (['"time","note; a","x"', "1,walk,2"], (",", False)),
        (["time,seconds_elapsed,z,y,x,note;a"], (",", False)),  # a header alone
        (["time,x,y,z,note;a", "1,2,3"], (",", False)),  # a first row of the wrong width: the reader names it
        (["# exported; by a tool", "time;x;y;z", "1,5;2,5;3;4"], (";", True)),
        (["time\tx (m/s^2); raw\ty\tz", "1,5\t2\t3\t4"], ("\t", True)),
        (["time"], (",", False)),
    ],
)
def test_the_dialect_is_the_separator_the_header_and_its_first_row_agree_on(head, dialect):
    from hil.logs.table import sniff_dialect

    assert sniff_dialect(head) == dialect


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    unit=st.sampled_from([("ns", 0), ("µs", 3), ("ms", 6), ("s", 9)]),
    decimals=st.integers(0, 9),
    scientific=st.booleans(),
)
def test_an_epoch_time_in_any_unit_and_precision_reads_to_its_resolution(
    tmp_path_factory, real_log, unit, decimals, scientific
):
    """``time`` in ns, µs, ms or s, with 0-9 decimals (at most to the ns), as plain or scientific
    notation with all its digits: the samples of the export, to the resolution written (at most 1 ms
    here: coarser is a rounded time, read by ``seconds_elapsed``)."""
    name, exponent = unit
    decimals = min(decimals, exponent)
    resolution_s = 10.0 ** (exponent - decimals - 9)
    if resolution_s > 1e-3:
        decimals = exponent - 6
        resolution_s = 1e-3

    def convert(ns: int) -> str:
        whole, fraction = divmod(ns, 10**exponent)
        text = f"{whole}" + (f".{fraction:0{exponent}d}"[: decimals + 1] if decimals else "")
        if scientific:
            digits = text.replace(".", "")
            text = f"{digits[0]}.{digits[1:]}E+{len(str(whole)) - 1}"
        return text

    log = read_log(real_export(tmp_path_factory.mktemp("unit") / "e", with_time(convert)))
    assert_times_close(log, real_log, resolution_s + 1e-6)

"""A phone export cut short — the app killed while it wrote, a copy or download stopped mid-way: the file
ends in the middle of a line (CSV) or of a record (JSON). Before, the whole recording was refused for its
last few bytes (``Gyroscope.csv:34649: 4 values, expected 5``; JSON: "record 896 is not JSON"). Now
every complete row or record is read, the cut one is dropped, and the log's notes (and a warning) say so,
naming the file and line. A last line without a line break is dropped even when it parses: a cut inside
its last number ("0.0036" of "0.00366519") leaves a row that reads, wrong; one sample lost, said.

Cut at drawn byte offsets of the real Sensor Logger export (``../shared/data``, read, never copied), as
it is, gzipped and zipped; the CSV and JSON exports, the project's CSV and the tyrex layout.
"""

from __future__ import annotations

import gzip
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from test_logs_layouts_beside import REAL, REAL_FILES, json_records, real_export

from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

KIND_OF = {
    "Gyroscope.csv": SensorKind.GYR,
    "TotalAcceleration.csv": SensorKind.ACC,
    "Magnetometer.csv": SensorKind.MAG,
}
SETTINGS = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@pytest.fixture(scope="module")
def export(tmp_path_factory):
    """The real export's first lines of each file, and the log read from it."""
    folder = real_export(tmp_path_factory.mktemp("whole") / "export")
    return folder, read_log(folder)


def assert_prefix(log, reference, kind: SensorKind, complete: int, partial_read: bool) -> None:
    """``log``'s ``kind`` holds ``reference``'s first ``complete`` samples bit for bit (and one more, a row
    the cut left readable, when ``partial_read``); every other sensor whole."""
    for other, stream in reference.streams.items():
        got = log.streams[other]
        if other is not kind:
            np.testing.assert_array_equal(got.t, stream.t)
            continue
        assert len(got.t) == complete + partial_read, (len(got.t), complete, partial_read)
        np.testing.assert_array_equal(got.t[:complete], stream.t[:complete])
        np.testing.assert_array_equal(got.xyz[:complete], stream.xyz[:complete])


def cut_csv(text: bytes, back: int) -> tuple[bytes, int, bytes]:
    """``text`` cut ``back`` bytes before its end, moved off a line break: the bytes, the complete data rows
    before the cut, and the cut line's bytes."""
    cut = len(text) - back
    while text[cut - 1 : cut] == b"\n" or text[cut : cut + 1] == b"\n":
        cut -= 1
    kept = text[:cut]
    complete = kept.count(b"\n") - 1  # the header's line break is no row's
    return kept, complete, kept[kept.rfind(b"\n") + 1 :]


def readable(line: bytes) -> bool:
    """Whether a cut line is still a row of the export's five cells, each a number."""
    cells = line.decode().split(",")
    try:
        [float(c) for c in cells]
    except ValueError:
        return False
    return len(cells) == 5


@SETTINGS
@given(
    name=st.sampled_from(REAL_FILES), back=st.integers(1, 6_000), how=st.sampled_from(["plain", "gz", "zip"])
)
def test_a_csv_export_cut_inside_a_line_reads_every_row_before_the_cut(tmp_path, export, name, back, how):
    folder, reference = export
    whole = (folder / name).read_bytes()
    kept, complete, partial = cut_csv(whole, back)
    out = tmp_path / f"cut-{how}-{back}"
    if out.exists():
        return  # the same example again (Hypothesis replays): already checked
    out.mkdir()
    for other in REAL_FILES:
        data = kept if other == name else (folder / other).read_bytes()
        if how == "gz":
            (out / f"{other}.gz").write_bytes(gzip.compress(data))
        else:
            (out / other).write_bytes(data)
    path: Path = out
    if how == "zip":
        path = tmp_path / f"cut-{back}.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for other in REAL_FILES:
                z.write(out / other, f"Recording/{other}")
    log = read_log(path)
    assert_prefix(log, reference, KIND_OF[name], complete, False)  # a cut row that reads is dropped too
    notes = [n for n in log.notes if "cut short" in n]
    assert len(notes) == 1 and name in notes[0] and f":{complete + 2}" in notes[0], notes
    if readable(partial):
        assert "no line break after it" in notes[0]


def test_the_real_export_cut_in_its_last_line_reads_with_a_warning(tmp_path, caplog):
    """The shape a user meets: the app's file ends in ``…,-0.0146607663`` (four cells of five)."""
    folder = tmp_path / "export"
    folder.mkdir()
    for name in REAL_FILES:
        data = (REAL / name).read_bytes()
        (folder / name).write_bytes(data[:-30] if name == "Gyroscope.csv" else data)
    log = read_log(folder)
    lines = (REAL / "Gyroscope.csv").read_bytes().count(b"\n")
    assert len(log.streams[SensorKind.GYR].t) == lines - 2  # the header, the cut row
    assert any("Gyroscope.csv" in r.message and "cut short" in r.message for r in caplog.records)


def test_a_file_without_its_final_line_break_drops_its_last_row_and_says_so(tmp_path, export):
    """Its last line may be whole or cut mid-number: nothing tells them apart, so it is dropped (one
    sample), named; the shipped exports end in a line break and read every row."""
    folder, reference = export
    out = tmp_path / "export"
    out.mkdir()
    for name in REAL_FILES:
        assert (REAL / name).read_bytes().endswith(b"\n")  # the app's files: every row read
        (out / name).write_bytes((folder / name).read_bytes().rstrip(b"\n"))
    log = read_log(out)
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].t, stream.t[:-1])
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz[:-1])
    notes = [n for n in log.notes if "cut short" in n]
    assert sorted(n.split(":")[0].rpartition("/")[2] for n in notes) == sorted(REAL_FILES), notes


@SETTINGS
@given(
    name=st.sampled_from(REAL_FILES),
    row=st.integers(0, 9),
    keep=st.integers(1, 30),
    how=st.sampled_from(["plain", "gz", "zip"]),
)
def test_a_last_line_cut_inside_a_number_is_never_read_as_a_value(tmp_path, name, row, keep, how):
    """The file ends in the middle of a number of its last row, the row still five numbers
    ("…,0.0036" of "…,0.00366519158706069"): before, that row was read, its value wrong. Now dropped,
    named; every row before it read bit for bit."""
    out = tmp_path / f"mid-{name}-{row}-{keep}-{how}"
    if out.exists():
        return  # the same example again (Hypothesis replays): already checked
    whole = real_export(out / "whole", lambda n, lines: lines[: 12 + row])
    folder = out / "cut"
    folder.mkdir()
    for other in REAL_FILES:
        data = (whole / other).read_bytes()
        if other == name:
            last = data.rstrip(b"\n").rsplit(b"\n", 1)[1]
            cells = last.split(b",")
            digits = len(cells[-1]) - cells[-1].find(b".") - 1
            cut = len(data.rstrip(b"\n")) - max(1, digits - keep)  # inside the last number's decimals
            data = data[:cut]
            assume(readable(data.rsplit(b"\n", 1)[1]))  # "…,0" cut to "…,": that one was dropped before
        (folder / f"{other}.gz" if how == "gz" else folder / other).write_bytes(
            gzip.compress(data) if how == "gz" else data
        )
    path: Path = folder
    if how == "zip":
        path = out / "cut.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for other in REAL_FILES:
                z.write(folder / other, f"Recording/{other}")
    reference = read_log(whole)
    log = read_log(path)
    assert_prefix(log, reference, KIND_OF[name], len(reference.streams[KIND_OF[name]].t) - 1, False)
    notes = [n for n in log.notes if "cut short" in n]
    assert len(notes) == 1 and name in notes[0] and "no line break" in notes[0], notes


def test_a_cut_line_in_the_middle_of_a_file_is_still_an_error_naming_it(tmp_path):
    """Only the last line may be cut: a short row followed by more rows is a damaged file."""
    out = real_export(tmp_path / "e", lambda name, lines: [*lines[:50], lines[50][:20], *lines[51:]])
    with pytest.raises(InputFormatError, match="values, expected") as err:
        read_log(out)
    assert err.value.line == 51


@SETTINGS
@given(fraction=st.floats(0.0, 0.9999))
def test_a_json_export_cut_anywhere_reads_every_record_before_the_cut(tmp_path, export, fraction):
    """Cut anywhere after each sensor's first record (the export groups them by sensor; cut before a
    sensor's first, the log lacks that sensor, an error that says so)."""
    _, reference = export
    whole = json.dumps(json_records(), indent=2).encode()
    first = whole.find(b"}", whole.find(b'"Magnetometer"')) + 1  # every sensor has a record before it
    cut = first + int((len(whole) - first) * fraction)
    path = tmp_path / f"Recording-{cut}.json"
    path.write_bytes(whole[:cut])
    records = json.loads(whole)
    done = 0  # records whole before the cut: their closing brace is in the kept bytes
    position = 0
    for _ in records:
        end = whole.find(b"}", position)
        if end >= cut:
            break
        done, position = done + 1, end + 1
    log = read_log(path, format="sensorlogger-json")
    counts = {kind: 0 for kind in KIND_OF.values()}
    for record in records[:done]:
        counts[KIND_OF[str(record["sensor"]) + ".csv"]] += 1
    for kind, stream in log.streams.items():
        n = counts[kind]
        assert len(stream.t) == n
        np.testing.assert_array_equal(stream.t, reference.streams[kind].t[:n])
    notes = [n for n in log.notes if "cut short" in n]
    assert len(notes) == 1 and path.name in notes[0]


def test_the_projects_csv_and_tyrex_cut_short_read_what_is_whole(tmp_path):
    rows = ["t_s,sensor,x,y,z,w"] + [f"{i * 0.01:.2f},gyr,0.1,0.2,0.3," for i in range(5)]
    rows += [f"{i * 0.01:.2f},acc,0.1,0.2,9.8," for i in range(5)]
    path = tmp_path / "log.csv"
    path.write_text("\n".join(rows) + "\n0.05,ac", encoding="utf-8")
    log = read_log(path)
    assert [len(s.t) for s in log.streams.values()] == [5, 5]
    assert any("log.csv:12" in n and "cut short" in n for n in log.notes)
    trial = tmp_path / "tyrex"
    trial.mkdir()
    for name, z in (
        ("accelerometer.txt", 9.8),
        ("gyroscope-calibrated.txt", 0.0),
        ("magnetometer-calibrated.txt", 40.0),
    ):
        lines = [f"{i * 0.01:.2f} 0.1 0.2 {z}" for i in range(20)]
        (trial / name).write_text("\n".join(lines) + "\n0.20 0.1", encoding="utf-8")
    log = read_log(trial, format="tyrex")
    assert all(len(s.t) == 20 for s in log.streams.values())
    assert sum("cut short" in n for n in log.notes) == 3

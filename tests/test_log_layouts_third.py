"""Phone exports laid out a little differently from what the other tests walk, and values that parse but
are absurd (docs/formats.md lists each layout and its test): files in UTF-16 (Excel's "Unicode text") or
with a Latin-1 header, line endings and blank lines of every kind, exports packed in a tar or a zip inside
a zip, a Sensor Logger file without ``seconds_elapsed``, a ``time`` that is no time of the recording.
Each variant is built here from the real exports in ``../shared/data`` (read, never copied into the
project) and must read as the export itself, or end in one :class:`InputFormatError` naming the file."""

from __future__ import annotations

import codecs
import io
import shutil
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
REAL = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 400  # per file: the header and ~8 s of the recording
TYREX = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_AR"

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")


def real_lines(name: str, lines: int = REAL_LINES) -> list[str]:
    """The first ``lines`` lines of one of the real export's files (header first), without line breaks."""
    with open(REAL / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def real_export(
    folder: Path,
    edit=lambda name, lines: lines,
    encode=lambda name, text: text.encode("utf-8"),
    newline: str = "\n",
    ending: str = "\n",
) -> Path:
    """The first :data:`REAL_LINES` lines of each of the real export's files into ``folder``: the lines
    through ``edit(name, lines)``, joined by ``newline``, ``ending`` after the last, bytes by
    ``encode(name, text)``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        lines = edit(name, real_lines(name))
        (folder / name).write_bytes(encode(name, newline.join(lines) + ending))
    return folder


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


# --------------------------------------------------------------------------- 1. encodings
def utf16(order: str):
    """Text as a Windows tool saves "Unicode": UTF-16 with its byte-order mark."""
    bom = codecs.BOM_UTF16_LE if order == "le" else codecs.BOM_UTF16_BE
    return lambda name, text: bom + text.encode(f"utf-16-{order}")


def tabs(name: str, lines: list[str]) -> list[str]:
    return [line.replace(",", "\t") for line in lines]


@pytest.mark.parametrize(
    ("encode", "edit", "newline"),
    [
        (utf16("le"), tabs, "\r\n"),  # Excel's "Unicode text": tab-separated UTF-16 LE, CRLF
        (utf16("le"), lambda name, lines: lines, "\n"),
        (utf16("be"), lambda name, lines: lines, "\r\n"),
        (lambda name, text: codecs.BOM_UTF32_LE + text.encode("utf-32-le"), tabs, "\r\n"),
    ],
    ids=["excel unicode text", "utf-16 le commas", "utf-16 be", "utf-32 le"],
)
def test_an_export_saved_in_utf16_reads_as_the_export(tmp_path, real_log, encode, edit, newline):
    """Was "not a recognised log": every file's first bytes were NULs and a byte-order mark."""
    folder = real_export(tmp_path / "rec", edit, encode, newline, newline)
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


def test_a_phyphox_export_saved_in_utf16_reads_as_in_utf8(tmp_path, real_log):
    headers = {
        "Accelerometer.csv": ("Acceleration x (m/s^2)", ACC),
        "Gyroscope.csv": ("Gyroscope x (rad/s)", GYR),
        "Magnetometer.csv": ("Magnetic field x (µT)", MAG),
    }
    logs = []
    for encoding in ("utf-8", "utf-16"):
        folder = tmp_path / encoding
        folder.mkdir()
        for name, (x_label, kind) in headers.items():
            stream = real_log.streams[kind]
            columns = ["Time (s)", *(x_label.replace(" x ", f" {a} ") for a in "xyz")]
            rows = ["\t".join(f'"{c}"' for c in columns)]
            rows += [
                "\t".join(f"{v:.9E}" for v in (t, *xyz)) for t, xyz in zip(stream.t, stream.xyz, strict=True)
            ]
            (folder / name).write_bytes(("\r\n".join(rows) + "\r\n").encode(encoding))
        logs.append(read_log(folder))
    assert logs[1].format == "phyphox"
    assert_same_samples(logs[1], logs[0])


@pytest.mark.parametrize(
    ("tail", "line", "what"),
    [
        (b"\x00\xd8" + "\n".encode("utf-16-le"), 3, "surrogate"),  # a lone surrogate on line 3
        (b"\x31", 3, "truncated"),  # an odd byte at the end
    ],
)
def test_utf16_that_is_not_text_is_a_typed_error_naming_the_file_and_line(tmp_path, tail, line, what):
    folder = real_export(tmp_path / "rec")
    body = "time,seconds_elapsed,z,y,x\n1679068247609296600,0.41,0,0,0\n".encode("utf-16-le")
    (folder / "Gyroscope.csv").write_bytes(codecs.BOM_UTF16_LE + body + tail)
    with pytest.raises(InputFormatError, match=what) as err:
        read_log(folder)
    assert err.value.path.endswith("Gyroscope.csv") and err.value.line == line


def latin1_units(unit: str, name: str, encoding: str):
    def edit(file: str, lines: list[str]) -> list[str]:
        if file != name:
            return lines
        return ["time,seconds_elapsed," + ",".join(f"{a} ({unit})" for a in "zyx"), *lines[1:]]

    return edit, lambda file, text: text.encode(encoding)


@pytest.mark.parametrize("encoding", ["latin-1", "cp1252"])
def test_a_header_with_micro_tesla_or_degrees_in_a_legacy_encoding_is_read_and_converted(
    tmp_path, real_log, encoding
):
    """``z (µT)`` and ``z (°/s)`` saved in Latin-1 were "not UTF-8 text" on line 1."""
    edit, encode = latin1_units("µT", "Magnetometer.csv", encoding)
    assert_same_samples(read_log(real_export(tmp_path / "mag", edit, encode)), real_log)
    edit, encode = latin1_units("°/s", "Gyroscope.csv", encoding)
    log = read_log(real_export(tmp_path / "gyr", edit, encode))
    np.testing.assert_allclose(log.streams[GYR].xyz, real_log.streams[GYR].xyz * np.pi / 180, rtol=1e-12)


def test_a_byte_that_is_not_utf8_in_a_data_row_of_a_utf8_file_stays_an_error_naming_its_line(tmp_path):
    """Only a header may be in a legacy encoding: the same byte in a row of a UTF-8 file is damage."""
    folder = real_export(tmp_path / "rec")
    lines = (folder / "Gyroscope.csv").read_bytes().split(b"\n")
    lines[9] = lines[9] + b"\xb5"
    (folder / "Gyroscope.csv").write_bytes(b"\n".join(lines))
    with pytest.raises(InputFormatError, match="not UTF-8") as err:
        read_log(folder)
    assert err.value.path.endswith("Gyroscope.csv") and err.value.line == 10


@pytest.mark.parametrize(
    "metadata",
    [
        "version,device name,platform\n3,Téléphone,android\n".encode("latin-1"),
        "version,device name,platform,standardisation\n3,phone,ios,true\n".encode("utf-16"),
    ],
    ids=["latin-1", "utf-16"],
)
def test_a_metadata_file_in_another_encoding_does_not_stop_the_export(tmp_path, real_log, metadata):
    """``Metadata.csv`` (read for the platform only) re-saved by Excel was "not UTF-8 text"."""
    folder = real_export(tmp_path / "rec")
    (folder / "Metadata.csv").write_bytes(metadata)
    log = read_log(folder)
    assert_same_samples(log, real_log)
    assert any("iOS" in note for note in log.notes) == (b"i\x00o\x00s" in metadata)


# --------------------------------------------------------------------------- 2. line endings, blank lines
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    newline=st.sampled_from(["\n", "\r\n", "\r"]),
    ending=st.sampled_from(["", "\n", "\r\n", "\r"]),
    blanks=st.lists(st.sampled_from(["", " ", "  ", "\t"]), max_size=3),
    encoding=st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "utf-16-be-bom"]),
    quoted=st.booleans(),
)
def test_any_line_ending_trailing_blanks_encoding_and_quoting_reads_as_the_export(
    tmp_path_factory, real_log, newline, ending, blanks, encoding, quoted
):
    """A line of spaces at the end (an editor's) was "unparseable table (no single bad cell found)";
    UTF-16 was not recognised."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if quoted:  # every cell quoted, a space before the quote (a hand-made CSV)
            lines = [",".join(f' "{c}"' for c in line.split(",")) for line in lines]
        return lines + blanks

    def encode(name: str, text: str) -> bytes:
        if encoding == "utf-16-be-bom":
            return codecs.BOM_UTF16_BE + text.encode("utf-16-be")
        return text.encode(encoding)

    folder = real_export(tmp_path_factory.mktemp("endings") / "rec", edit, encode, newline, ending)
    reference = real_log
    if not ending and not blanks:  # a last data line without a line break may be cut short: dropped, said
        reference = read_log(
            real_export(tmp_path_factory.mktemp("ref") / "rec", lambda name, lines: lines[:-1])
        )
    assert_same_samples(read_log(folder), reference)


# --------------------------------------------------------------------------- 3. archives
def tar_of(folder: Path, archive: Path, mode: str, under: str = "Rec", litter: bool = False) -> Path:
    """``folder`` packed as ``tar`` does, under ``under`` (with macOS's ``._name`` companions)."""
    with tarfile.open(archive, mode) as tar:
        for f in sorted(folder.iterdir()):
            if litter:
                info = tarfile.TarInfo(f"{under}/._{f.name}")
                data = b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X"
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
            tar.add(f, f"{under}/{f.name}")
    return archive


@pytest.mark.parametrize(
    ("name", "mode"),
    [
        ("rec.tar", "w"),
        ("rec.tar.gz", "w:gz"),
        ("rec.tgz", "w:gz"),
        ("rec.tar.bz2", "w:bz2"),
        ("rec.tar.xz", "w:xz"),
    ],
)
def test_an_export_packed_in_a_tar_reads_as_the_export(tmp_path, real_log, name, mode):
    """A tar (``tar czf rec.tgz Rec``, macOS's ``._`` files beside) was "not a recognised log"."""
    archive = tar_of(real_export(tmp_path / "Rec"), tmp_path / name, mode, litter=True)
    assert detect_format(archive) == "sensorlogger"
    assert_same_samples(read_log(archive), real_log)
    folder = tmp_path / "holder"  # a folder holding the tar, as one holding the app's zip
    folder.mkdir()
    shutil.copy(archive, folder / name)
    assert_same_samples(read_log(folder), real_log)


def zip_of(folder: Path, archive: Path, under: str = "") -> Path:
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(folder.iterdir()):
            z.write(f, under + f.name)
    return archive


@pytest.mark.parametrize("under", ["", "Mail/", "Mail/Attachments/"])
def test_a_zip_holding_the_apps_zip_reads_as_the_export(tmp_path, real_log, under):
    """The app's zip mailed inside another zip (a folder or two deep) was "not a recognised log"."""
    inner = zip_of(real_export(tmp_path / "rec"), tmp_path / "Recording.zip")
    outer = tmp_path / "outer.zip"
    with zipfile.ZipFile(outer, "w") as z:
        z.write(inner, under + "Recording.zip")
        z.writestr("__MACOSX/._Recording.zip", b"\x00\x05\x16\x07")
    assert detect_format(outer) == "sensorlogger"
    assert_same_samples(read_log(outer), real_log)


def test_a_tyrex_trial_zipped_two_folders_deep_reads_with_its_exclusions(tmp_path):
    """Two shared folders: only one was left out of the names (tyrex looks at the top: unrecognised);
    zipped flat as ``<trial>.zip``, the benchmark's excluded intervals were matched against the file's
    name with ``.zip`` and silently not applied."""
    published = read_log(TYREX)
    deep = tmp_path / "deep.zip"
    with zipfile.ZipFile(deep, "w") as z:
        for f in sorted(TYREX.iterdir()):
            z.write(f, f"Downloads/{TYREX.name}/{f.name}")
    flat = zip_of(TYREX, tmp_path / f"{TYREX.name}.zip")
    for archive in (deep, flat):
        log = read_log(archive)
        assert log.format == "tyrex" and log.truth is not None and published.truth is not None
        np.testing.assert_array_equal(log.truth.evaluate, published.truth.evaluate)
        assert any("excluded" in note for note in log.notes)


@pytest.mark.parametrize("damage", ["truncated", "garbage after the magic"])
def test_a_damaged_tar_is_a_typed_error_naming_it(tmp_path, damage):
    archive = tar_of(real_export(tmp_path / "Rec"), tmp_path / "rec.tar.gz", "w:gz")
    data = archive.read_bytes()
    archive.write_bytes(
        data[: len(data) // 2] if damage == "truncated" else data[:10] + bytes(range(256)) * 8
    )
    with pytest.raises(InputFormatError) as err:
        read_log(archive)
    assert "rec.tar.gz" in str(err.value)


def test_a_tar_of_too_many_entries_is_refused_naming_it(tmp_path, monkeypatch):
    from hil.logs import archive as archive_module

    monkeypatch.setattr(archive_module, "MAX_MEMBERS", 5)
    archive = tmp_path / "many.tar"
    with tarfile.open(archive, "w") as tar:
        for i in range(10):
            info = tarfile.TarInfo(f"Rec/file{i}.csv")
            tar.addfile(info, io.BytesIO(b""))
    with pytest.raises(InputFormatError, match="more than 5 entries") as err:
        read_log(archive)
    assert err.value.path == str(archive)


# --------------------------------------------------------------------------- 4. columns
def drop_column(column: str):
    def edit(name: str, lines: list[str]) -> list[str]:
        index = lines[0].split(",").index(column)
        return [",".join(c for i, c in enumerate(line.split(",")) if i != index) for line in lines]

    return edit


def test_a_sensor_logger_export_without_seconds_elapsed_is_read_as_sensor_logger(tmp_path, real_log):
    """``time,z,y,x`` was detected as phyphox, which read the ns epoch as seconds (samples 53 billion
    years on) without a word."""
    folder = real_export(tmp_path / "rec", drop_column("seconds_elapsed"))
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)
    with pytest.raises(InputFormatError, match="epoch") as err:
        read_log(folder, "phyphox")
    assert err.value.column == "time"


def test_uncalibrated_metadata_and_annotation_files_beside_the_calibrated_ones_change_nothing(
    tmp_path, real_log
):
    folder = real_export(tmp_path / "rec")
    for name in REAL_FILES:
        lines = real_lines(name)
        uncalibrated = name.replace(".csv", "Uncalibrated.csv").replace("TotalAcceleration", "Accelerometer")
        rows = [lines[0] + ",biasZ,biasY,biasX", *(line + ",0.1,0.2,0.3" for line in lines[1:])]
        (folder / uncalibrated).write_text("\n".join(rows) + "\n")
    (folder / "Metadata.csv").write_text("version,device name,platform,appVersion\n3,SM-A520F,android,1.18\n")
    (folder / "Annotation.csv").write_text("time,seconds_elapsed,text\n1679068249000000000,1.8,hello\n")
    assert_same_samples(read_log(folder), real_log)


# --------------------------------------------------------------------------- 5. absurd times
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    row=st.integers(1, REAL_LINES - 1),
    time=st.one_of(
        # the last: int64, but as a float64 past it
        st.sampled_from([0, -1, 10**18, -(10**18), 10**18 + 1, 9 * 10**18, 2**63 - 512]),
        st.integers(-9 * 10**18, 10**18),
        st.integers(1679068247609296600 + 32 * 86400 * 10**9, 2**63 - 1),
    ),
    name=st.sampled_from(REAL_FILES),
)
def test_a_row_whose_time_is_no_time_of_the_recording_is_a_nan_sample_not_the_clock_origin(
    tmp_path_factory, real_log, row, time, name
):
    """A row at ``time`` 0, a negative time or 1e18 ns (2001) in a recording of 2023 became the clock's
    origin: every other sample 1.7e9 (or 6.8e8) s on, the replay split at the 'gap' and run from there."""

    def edit(file: str, lines: list[str]) -> list[str]:
        if file == name:
            cells = lines[row].split(",")
            lines[row] = ",".join([str(time), *cells[1:]])
        return lines

    log = read_log(real_export(tmp_path_factory.mktemp("stray") / "rec", edit))
    kind = {"Gyroscope.csv": GYR, "TotalAcceleration.csv": ACC, "Magnetometer.csv": MAG}[name]
    stream, reference = log.streams[kind], real_log.streams[kind]
    assert np.isnan(stream.xyz[row - 1]).all()
    keep = np.arange(len(reference)) != row - 1
    if row - 1 != 0:  # the other rows' times are the recording's (its first row may be the origin)
        for k in (GYR, ACC, MAG):
            mine = log.streams[k] if k != kind else stream
            sel = keep if k == kind else slice(None)
            np.testing.assert_array_equal(mine.t[sel], real_log.streams[k].t[sel])
    assert all(abs(t) < 3600 for s in log.streams.values() for t in s.t[np.isfinite(s.xyz).all(axis=1)])
    assert any("no time of this recording" in note for note in log.notes)

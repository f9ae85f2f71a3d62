"""More variants of the real recordings, each a file a user could bring and that once ended in a raw
NumPy traceback or a misleading answer: BROAD trials whose variables are not what the reader assumed
(a ``movement`` mask of another length, a sampling rate that is empty, text, 0 or inf, readings held as
text, cells or complex numbers, ground truth of zeros); tyrex trials whose Qualisys ``FrameRate`` or
``timeAlignment.txt`` is no usable number; Sensor Logger exports with an empty sensor file or a header
in capitals. Every variant is derived here from the real files in ``../shared/data`` (never copied into
the project); each must end in the log it holds or in one :class:`InputFormatError` naming the file and
the variable, column or line."""

from __future__ import annotations

import gzip
import io
import shutil
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, project_csv, read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
BROAD = SHARED_DATA / "broad" / "01_undisturbed_slow_rotation_A.mat"
TYREX = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Texting"
SENSOR_LOGGER = SHARED_DATA / "sensorlogger-android"
SL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
SL_LINES = 1000  # per file: the header and ~20 s of the recording
BROAD_SAMPLES = 2000


# --------------------------------------------------------------------------- BROAD
@pytest.fixture(scope="module")
def broad_trial() -> dict[str, np.ndarray]:
    """The first :data:`BROAD_SAMPLES` samples of a real BROAD trial's variables."""
    mat = scipy.io.loadmat(BROAD)
    return {
        key: value if key in ("sampling_rate", "info") else value[:BROAD_SAMPLES]
        for key, value in mat.items()
        if not key.startswith("__")
    }


def broad_variant(folder: Path, trial: dict[str, np.ndarray], **changed: object) -> Path:
    path = folder / "trial.mat"
    scipy.io.savemat(path, {**trial, **changed})
    return path


def test_a_cut_real_broad_trial_reads_as_it_is(tmp_path, broad_trial):
    log = read_log(broad_variant(tmp_path, broad_trial))
    assert log.format == "broad" and len(log.streams[GYR]) == BROAD_SAMPLES
    np.testing.assert_array_equal(log.streams[MAG].xyz, broad_trial["imu_mag"])
    assert log.truth is not None and log.truth.evaluate.sum() == np.count_nonzero(
        broad_trial["movement"].reshape(-1) & np.all(np.isfinite(broad_trial["opt_quat"]), axis=1)
    )


@pytest.mark.parametrize("name", ["TRIAL.MAT", "Trial.Mat", "trial.mat.gz", "TRIAL.MAT.GZ"])
def test_a_broad_trial_named_in_capitals_or_gzipped_reads_as_the_trial(tmp_path, broad_trial, name):
    """A trial renamed in capitals (a FAT card, a Windows copy) or gzipped by hand: its suffix was read as
    ``.mat`` only, lower case and plain, so it was "not a recognised log"; every format reads a ``.gz``."""
    data = broad_variant(tmp_path, broad_trial).read_bytes()
    path = tmp_path / "renamed" / name
    path.parent.mkdir()
    path.write_bytes(gzip.compress(data) if name.lower().endswith(".gz") else data)
    log = read_log(path)
    assert log.format == "broad"
    np.testing.assert_array_equal(log.streams[MAG].xyz, broad_trial["imu_mag"])


BROAD_VARIANTS = {
    # a movement mask cut short: numpy's broadcasting error from ``movement & finite``
    "movement of another length": ({"movement": np.ones((10, 1), np.uint8)}, "movement", "one per sample"),
    # an empty sampling_rate: IndexError; a text one: ValueError from float()
    "no sampling rate": ({"sampling_rate": np.zeros((0, 0))}, "sampling_rate", "expected one"),
    "a sampling rate in words": ({"sampling_rate": "fast"}, "sampling_rate", "text"),
    # 0 and inf passed ``rate > 0`` (inf: every sample at t = 0); 1e300 put them 1e-300 s apart
    "an infinite sampling rate": ({"sampling_rate": np.array([[np.inf]])}, "sampling_rate", "outside"),
    "a sampling rate of 1e300": ({"sampling_rate": np.array([[1e300]])}, "sampling_rate", "outside"),
    "a zero sampling rate": ({"sampling_rate": np.array([[0.0]])}, "sampling_rate", "outside"),
    # readings as text or cells: ValueError from SensorStream; complex: imaginary parts silently dropped
    "gyroscope as text": ({"imu_gyr": np.array([["a", "b", "c"]] * BROAD_SAMPLES)}, "imu_gyr", "text"),
    "gyroscope as cells": (
        {"imu_gyr": np.array([[1, 2, 3]] * BROAD_SAMPLES, dtype=object)}, "imu_gyr", "cell"
    ),
    "complex magnetometer": (
        {"imu_mag": np.full((BROAD_SAMPLES, 3), 20 + 5j)}, "imu_mag", "complex"
    ),
    # zeros as ground truth: a NumericalError that named no file
    "ground truth of zeros": ({"opt_quat": np.zeros((BROAD_SAMPLES, 4))}, "opt_quat", "no rotation"),
}  # fmt: skip


@pytest.mark.parametrize("variant", BROAD_VARIANTS)
def test_a_broad_trial_whose_variables_are_not_what_they_should_be_is_a_typed_error_naming_one(
    tmp_path, broad_trial, variant
):
    changed, variable, message = BROAD_VARIANTS[variant]
    path = broad_variant(tmp_path, broad_trial, **changed)
    with pytest.raises(InputFormatError, match=message) as err:
        read_log(path, "broad")
    assert str(path) in str(err.value) and f"(column {variable})" in str(err.value)


# --------------------------------------------------------------------------- tyrex
def tyrex_variant(folder: Path, frame_rate: object = None, alignment: bytes | None = None) -> Path:
    """The real trial with its Qualisys ``FrameRate`` and/or its ``timeAlignment.txt`` replaced."""
    trial = folder / TYREX.name
    shutil.copytree(TYREX, trial)
    if frame_rate is not None:
        mat = scipy.io.loadmat(TYREX / "qualisys.mat", squeeze_me=True, struct_as_record=False)
        key = next(k for k in mat if not k.startswith("__"))
        qtm = mat[key]
        fields = {name: getattr(qtm, name) for name in qtm._fieldnames}
        fields["RigidBodies"] = {name: getattr(qtm.RigidBodies, name) for name in qtm.RigidBodies._fieldnames}
        fields["FrameRate"] = frame_rate
        buffer = io.BytesIO()
        scipy.io.savemat(buffer, {key: fields})
        (trial / "qualisys.mat").chmod(0o644)
        (trial / "qualisys.mat").write_bytes(buffer.getvalue())
    if alignment is not None:
        (trial / "timeAlignment.txt").chmod(0o644)
        (trial / "timeAlignment.txt").write_bytes(alignment)
    return trial


@pytest.mark.parametrize(
    ("frame_rate", "message"),
    [
        (0.0, "outside"),
        (np.nan, "outside"),
        ("sixty", "holds text, expected real numbers"),
        (np.zeros(0), "expected one"),
    ],
    ids=["zero", "nan", "text", "empty"],
)
def test_a_qualisys_frame_rate_that_is_no_rate_is_a_typed_error_naming_it(tmp_path, frame_rate, message):
    """0 and NaN once divided the frame numbers into NaN truth times (nothing evaluated, silently); text
    and an empty array were a ValueError and a TypeError from ``float()``."""
    trial = tyrex_variant(tmp_path, frame_rate=frame_rate)
    with pytest.raises(InputFormatError, match=message) as err:
        read_log(trial)
    assert "qualisys.mat" in str(err.value) and "(column FrameRate)" in str(err.value)


def test_a_time_alignment_that_is_nan_is_a_typed_error_naming_the_file(tmp_path):
    """A ``nan`` offset once put every truth frame at NaN s: a trial with nothing to evaluate, silently."""
    trial = tyrex_variant(tmp_path, alignment=b"nan\n")
    with pytest.raises(InputFormatError, match="clock offset") as err:
        read_log(trial)
    assert "timeAlignment.txt" in str(err.value)


def test_the_real_tyrex_trial_rewritten_with_its_own_frame_rate_reads_as_published(tmp_path):
    published = read_log(TYREX)
    rewritten = read_log(tyrex_variant(tmp_path, frame_rate=60.0))
    assert published.truth is not None and rewritten.truth is not None
    np.testing.assert_array_equal(rewritten.truth.t, published.truth.t)


# --------------------------------------------------------------------------- Sensor Logger
def sensor_logger_export(folder: Path, edit=lambda name, lines: lines) -> Path:
    """The first :data:`SL_LINES` lines of each file of the real export, through ``edit(name, lines)``
    (which returns the lines to write)."""
    folder.mkdir(parents=True)
    for name in SL_FILES:
        with open(SENSOR_LOGGER / name, encoding="utf-8") as f:
            lines = [next(f).rstrip("\n") for _ in range(SL_LINES)]
        lines = edit(name, lines)
        (folder / name).write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def real_sensor_logger(tmp_path_factory):
    return read_log(sensor_logger_export(tmp_path_factory.mktemp("sl") / "export"))


def test_an_empty_gyroscope_file_is_named_not_the_export_unrecognised_and_its_files_offered_as_logs(tmp_path):
    """A 0-byte ``Gyroscope.csv`` once made detection give up on the whole export ("not a recognised
    log") and suggest replaying ``Magnetometer.csv`` on its own."""
    folder = sensor_logger_export(
        tmp_path / "rec", lambda name, lines: [] if name == "Gyroscope.csv" else lines
    )
    assert detect_format(folder) == "sensorlogger"
    with pytest.raises(InputFormatError, match="empty file") as err:
        read_log(folder)
    assert "Gyroscope.csv" in str(err.value) and "not a recognised log" not in str(err.value)


def test_an_empty_magnetometer_file_is_a_6_axis_log_as_a_header_only_one_is(tmp_path, real_sensor_logger):
    folder = sensor_logger_export(
        tmp_path / "rec", lambda name, lines: [] if name == "Magnetometer.csv" else lines
    )
    log = read_log(folder)
    assert log.six_axis and any("Magnetometer.csv is empty" in note for note in log.notes)
    for kind in (GYR, ACC):
        np.testing.assert_array_equal(log.streams[kind].xyz, real_sensor_logger.streams[kind].xyz)


def test_a_header_in_capitals_is_read_as_the_export_it_was_detected_as(tmp_path, real_sensor_logger):
    """Detection read ``TIME,SECONDS_ELAPSED,Z,Y,X`` whatever its case, the reader then refused it:
    "no 'time' or 'seconds_elapsed' column"."""
    folder = sensor_logger_export(tmp_path / "rec", lambda name, lines: [lines[0].upper(), *lines[1:]])
    assert detect_format(folder) == "sensorlogger"
    log = read_log(folder)
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(log.streams[kind].t, real_sensor_logger.streams[kind].t)
        np.testing.assert_array_equal(log.streams[kind].xyz, real_sensor_logger.streams[kind].xyz)


def gzipped(folder: Path) -> Path:
    """Each file of ``folder`` replaced by its gzip (``Gyroscope.csv.gz``), as a backup tool leaves it."""
    for f in sorted(folder.iterdir()):
        f.with_name(f.name + ".gz").write_bytes(gzip.compress(f.read_bytes()))
        f.unlink()
    return folder


def test_a_sensor_logger_export_of_gzipped_files_reads_as_the_export(tmp_path, real_sensor_logger):
    """``Gyroscope.csv.gz`` & co. were not recognised (the reader knew the names without ``.gz`` only),
    though the container decompresses ``.gz`` members as it reads them; in a folder or in a zip."""
    folder = gzipped(sensor_logger_export(tmp_path / "rec"))
    archive = tmp_path / "rec.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.iterdir()):
            z.write(f, f"Rec/{f.name}")
    for path in (folder, archive):
        assert detect_format(path) == "sensorlogger"
        log = read_log(path)
        assert any(".csv.gz" in note for note in log.notes)
        for kind in (GYR, ACC, MAG):
            np.testing.assert_array_equal(log.streams[kind].t, real_sensor_logger.streams[kind].t)
            np.testing.assert_array_equal(log.streams[kind].xyz, real_sensor_logger.streams[kind].xyz)


def test_a_gzipped_project_csv_reads_as_the_csv(tmp_path, real_sensor_logger):
    plain = project_csv.write(real_sensor_logger, tmp_path / "log.csv")
    packed = tmp_path / "packed" / "log.csv.gz"
    packed.parent.mkdir()
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    assert detect_format(packed) == "csv"
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(read_log(packed).streams[kind].xyz, read_log(plain).streams[kind].xyz)


def test_a_gz_member_with_a_corrupt_byte_is_a_typed_error_naming_it(tmp_path):
    """A flipped byte inside a ``.gz``'s deflate stream raised ``zlib.error`` (not an OSError: it passed
    the reader's guard) out of ``hil replay``; here in the published tyrex trial's gyroscope file."""
    trial = tmp_path / TYREX.name
    shutil.copytree(TYREX, trial)
    member = trial / "gyroscope-calibrated.txt.gz"
    data = member.read_bytes()
    for at in range(100, 400):  # the first flip that breaks the deflate stream itself (not just the CRC)
        broken = data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1 :]
        try:
            gzip.decompress(broken)
        except zlib.error:
            break
        except (OSError, EOFError):  # a bad CRC or length only: the stream itself still inflates
            continue
    else:
        pytest.fail("no single flipped byte broke the deflate stream")
    member.chmod(0o644)
    member.write_bytes(broken)
    with pytest.raises(InputFormatError, match="damaged") as err:
        read_log(trial)
    assert "gyroscope-calibrated.txt.gz" in str(err.value)

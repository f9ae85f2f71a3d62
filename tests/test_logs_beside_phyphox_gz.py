"""A phyphox export whose files are gzipped (``gzip -r`` on the folder, a backup tool) reads as the export.

docs/formats.md promises that a member whose name ends in ``.gz`` is read decompressed "in every format";
phyphox's reader looked only at ``.csv`` members, so such an export was "not a recognised log" (status 2),
and a ``meta/time.csv.gz`` left the built-in exports unalignable. Two copies of one table (``Gyroscope.csv``
beside its ``Gyroscope.csv.gz``) are read once when their bytes are the same, an error naming both when
they differ — as in the Sensor Logger and tyrex readers — never one of them passed over in silence.
"""

from __future__ import annotations

import gzip
import zipfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_phone_exports import HEAD, builtin_export, motion, phyphox_csv

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError
from tests.log_support import assert_same_samples

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
TABLES = {ACC: "Accelerometer.csv", GYR: "Gyroscope.csv", MAG: "Magnetometer.csv"}


def experiment(folder: Path) -> Path:
    """A phyphox experiment's export: one table per sensor, one clock."""
    t, gyr, acc, mag = motion()
    for kind, xyz in ((ACC, acc), (GYR, gyr), (MAG, mag)):
        phyphox_csv(folder / TABLES[kind], ("Time (s)", *HEAD[kind][:3]), t, xyz)
    return folder


def gzip_member(path: Path) -> Path:
    """``path`` replaced by ``path.gz`` holding its bytes (what ``gzip`` does to a file)."""
    packed = path.with_name(path.name + ".gz")
    packed.write_bytes(gzip.compress(path.read_bytes()))
    path.unlink()
    return packed


def zipped(folder: Path) -> Path:
    """``folder``'s files in a zip beside it (the folder is kept)."""
    archive = folder.with_suffix(".zip")
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    return archive


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(packed=st.sets(st.sampled_from(sorted(TABLES.values()))), as_zip=st.booleans())
def test_an_experiment_with_any_of_its_tables_gzipped_reads_as_the_export(tmp_path_factory, packed, as_zip):
    root = tmp_path_factory.mktemp("gz")
    reference = read_log(experiment(root / "plain"))
    folder = experiment(root / "packed")
    for name in packed:
        gzip_member(folder / name)
    log = read_log(zipped(folder) if as_zip else folder)
    assert log.format == "phyphox"
    assert_same_samples(log, reference)


def test_a_gzipped_experiment_replays_through_the_cli(tmp_path):
    folder = experiment(tmp_path / "exp")
    for name in TABLES.values():
        gzip_member(folder / name)
    assert main(["replay", str(folder), "--no-plots", "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "estimates.csv").stat().st_size > 0


def test_builtin_exports_gzipped_file_by_file_are_aligned_by_their_gzipped_meta_time(tmp_path):
    plain, packed = tmp_path / "plain", tmp_path / "packed"
    for root in (plain, packed):
        builtin_export(root / "Acceleration with g", ACC, 1_714_550_400.0)
        builtin_export(root / "Gyroscope", GYR, 1_714_550_400.25)
        builtin_export(root / "Magnetometer", MAG, 1_714_550_400.5)
    for f in sorted(packed.rglob("*.csv")):
        gzip_member(f)
    log = read_log(packed)
    assert_same_samples(log, read_log(plain))
    assert log.streams[GYR].t[0] == pytest.approx(0.25)
    assert any("aligned by meta/time.csv" in note for note in log.notes)


def test_a_table_beside_its_gzipped_copy_is_read_once_or_refused_when_they_differ(tmp_path):
    folder = experiment(tmp_path / "exp")
    reference = read_log(folder)
    gyro = folder / TABLES[GYR]
    text = gyro.read_text()
    gzip_member(gyro)
    gyro.write_text(text)
    log = read_log(folder)
    assert_same_samples(log, reference)
    assert any("read once" in note for note in log.notes)
    gyro.write_text(text.replace("E-", "E+", 1))  # one reading changed in the plain copy
    with pytest.raises(InputFormatError, match="bytes differ") as info:
        read_log(folder)
    assert "Gyroscope.csv" in str(info.value)

"""The Sensor Logger JSON export's ``Metadata`` record is read as the CSV export's ``Metadata.csv`` is.

The app's JSON export holds the recording's metadata as one record among the sensors' —
``{"sensor": "Metadata", "platform": "ios", "standardisation": "false", "appVersion": …}`` — where its
CSV export writes ``Metadata.csv``. Before: the JSON reader passed that record over as "another sensor",
so an iOS recording in its own frames (the app's default) was replayed from its JSON export with the
accelerometer upside down — the phone lying screen up replayed as screen down — while the CSV export of
the same recording was negated to Android's axes, noted. Now both exports of one recording give the same
samples and say the same, and two ``Metadata`` records that disagree are an error naming both. Built from
the real Android export (read, never copied), each sensor as the iOS app writes it."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples, needs_real_export, real_lines

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from protocol.errors import InputFormatError

pytestmark = needs_real_export

META = {"version": "3", "device name": "iPhone", "recording time": "2023-03-17_15-50-47",
        "platform": "iOS", "appVersion": "1.30.0", "device id": "abc"}  # fmt: skip


def _rows(name: str, scale: float = 1.0) -> list[list[str]]:
    rows = []
    for line in real_lines(name)[1:]:
        time, elapsed, *axes = line.split(",")
        rows.append([time, elapsed, *(repr(float(a) * scale) for a in axes)])
    return rows


def ios_recording() -> dict[str, list[list[str]]]:
    """The real recording as iOS writes it in its own frames: user acceleration and gravity negated."""
    return {
        "Gyroscope": _rows("Gyroscope.csv"),
        "Magnetometer": _rows("Magnetometer.csv"),
        "Accelerometer": _rows("TotalAcceleration.csv", 0.0),
        "Gravity": _rows("TotalAcceleration.csv", -1.0),
    }


def write_csv_export(folder: Path, metadata: dict[str, str] | None) -> Path:
    folder.mkdir(parents=True)
    for sensor, rows in ios_recording().items():
        lines = ["time,seconds_elapsed,z,y,x", *(",".join(r) for r in rows)]
        (folder / f"{sensor}.csv").write_text("\n".join(lines) + "\n")
    if metadata is not None:
        (folder / "Metadata.csv").write_text(",".join(metadata) + "\n" + ",".join(metadata.values()) + "\n")
    return folder


def write_json_export(path: Path, metadata: list[dict[str, object]], at: int) -> Path:
    records: list[dict[str, object]] = []
    for sensor, rows in ios_recording().items():
        for time, elapsed, z, y, x in rows:
            records.append(
                {"sensor": sensor, "time": time, "seconds_elapsed": elapsed, "z": z, "y": y, "x": x}
            )
    for i, meta in enumerate(metadata):
        records.insert(min(at + i, len(records)), {"sensor": "Metadata", **meta})
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(records, indent=2))
    return path


def android_acc() -> np.ndarray:
    return np.array([[float(a) for a in r[2:]] for r in _rows("TotalAcceleration.csv")])[:, ::-1]


def frames_notes(log) -> list[str]:
    """What the log says of the recording's frames, without where it read that."""
    return [n.split("(")[0] for n in log.notes if "iOS export" in n or "in g" in n]


SETTINGS = settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(
    standardisation=st.sampled_from([None, "false", "FALSE", "0", "true", True, False]),
    at=st.sampled_from([0, 1, 400, 10_000]),
)
def test_the_json_exports_metadata_decides_the_frames_as_metadata_csv_does(tmp_path, standardisation, at):
    meta: dict[str, object] = dict(META)
    if standardisation is not None:
        meta["standardisation"] = standardisation
    work = Path(tempfile.mkdtemp(dir=tmp_path))
    as_csv = {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in meta.items()}
    csv_log = read_log(write_csv_export(work / "csv", as_csv))
    json_path = write_json_export(work / "rec.json", [meta], at)
    assert detect_format(json_path) == "sensorlogger-json"
    json_log = read_log(json_path)
    assert_same_samples(json_log, csv_log)
    assert frames_notes(json_log) == frames_notes(csv_log) and frames_notes(json_log)
    on = standardisation in ("true", True)
    expected = -android_acc() if on else android_acc()
    np.testing.assert_allclose(json_log.streams[SensorKind.ACC].xyz, expected, rtol=1e-9, atol=1e-9)
    if not on:
        said = [n for n in json_log.notes if "iOS export" in n]
        assert "Metadata" in said[0] and "rec.json" in said[0], said


def test_a_json_export_without_metadata_reads_as_a_csv_export_without_metadata_csv(tmp_path):
    assert_same_samples(
        read_log(write_json_export(tmp_path / "rec.json", [], 0)),
        read_log(write_csv_export(tmp_path / "csv", None)),
    )


@pytest.mark.parametrize("value", ["maybe", ""])
def test_a_standardisation_neither_on_nor_off_is_an_error_naming_the_metadata_record(tmp_path, value):
    path = write_json_export(tmp_path / "rec.json", [{**META, "standardisation": value}], 5)
    with pytest.raises(InputFormatError, match="neither on") as raised:
        read_log(path)
    assert "rec.json" in str(raised.value) and "Metadata" in str(raised.value)


def test_two_metadata_records_that_disagree_are_an_error_naming_both(tmp_path):
    android = {**META, "platform": "android"}
    path = write_json_export(tmp_path / "rec.json", [META, android], 3)
    with pytest.raises(InputFormatError, match="second Metadata record") as raised:
        read_log(path)
    assert "rec.json" in str(raised.value) and "record 4" in str(raised.value)


def test_a_nested_platform_is_an_error_naming_the_key(tmp_path):
    path = write_json_export(tmp_path / "rec.json", [{**META, "platform": {"os": "iOS"}}], 0)
    with pytest.raises(InputFormatError, match="setting") as raised:
        read_log(path)
    assert "platform" in str(raised.value) and "rec.json" in str(raised.value)


def test_a_long_metadata_record_first_is_no_reason_to_miss_the_export(tmp_path):
    """A ``Metadata`` record of more lines than detection's first look (its per-sensor settings), first
    in the file: the export is still told by its first sensor record, and read with its settings."""
    meta = {**META, "standardisation": "false", **{f"sensor setting {i}": str(i) for i in range(60)}}
    path = write_json_export(tmp_path / "rec.json", [meta], 0)
    assert detect_format(path) == "sensorlogger-json"
    np.testing.assert_allclose(
        read_log(path).streams[SensorKind.ACC].xyz, android_acc(), rtol=1e-9, atol=1e-9
    )

"""An iOS Sensor Logger export whose ``Metadata.csv`` has no ``standardisation`` column, or one that says
neither on nor off.

The column came with "Standardise Units & Frames" in app version 1.29, off by default "to maintain
backwards compatibility" (github.com/tszheichoi/awesome-sensor-logger, CROSSPLATFORM.md): an iOS export
from before it holds iOS's own frames, its acceleration the other way round from Android's on every axis.
Before: such an export was read as if the setting were on — the accelerometer upside down, the phone
lying screen up replayed as screen down — and a value such as ``maybe`` or an empty cell was read as on
too. Now a missing column is read as iOS's own frames (negated to Android's, said), and a value that is
neither on nor off is an error naming ``Metadata.csv``. Built from the real Android export (read, never
copied), each file as the iOS app writes it."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_lines

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

pytestmark = needs_real_export

OLD_HEADER = ("version", "device name", "recording epoch time", "recording time", "recording timezone",
              "platform", "appVersion", "device id", "sensors", "sampleRateMs")  # fmt: skip
"""``Metadata.csv``'s columns as an app before 1.29 wrote them: no ``standardisation``."""
OLD_ROW = ("2", "iPhone", "1679068247375", "2023-03-17_15-50-47", "Europe/London", "iOS", "1.24.1", "abc",
           "Accelerometer|Gravity|Gyroscope|Magnetometer", "10|10|10|10")  # fmt: skip


def ios_export(folder: Path, metadata: str, acc_files: str) -> Path:
    """The real export as iOS writes it in its own frames (the acceleration's axes negated), beside
    ``metadata`` as its ``Metadata.csv``."""
    folder.mkdir(parents=True)
    for name in ("Gyroscope.csv", "Magnetometer.csv"):
        (folder / name).write_text("\n".join(real_lines(name)) + "\n")
    total = real_lines("TotalAcceleration.csv")

    def scaled(scale: float) -> str:
        rows = [total[0]]
        for line in total[1:]:
            time, elapsed, *axes = line.split(",")
            rows.append(",".join([time, elapsed, *(repr(float(a) * scale) for a in axes)]))
        return "\n".join(rows) + "\n"

    if acc_files == "user+gravity":
        (folder / "Gravity.csv").write_text(scaled(-1.0))
        (folder / "Accelerometer.csv").write_text(scaled(0.0))
    else:  # the raw accelerometer, in g in iOS's own units
        (folder / "AccelerometerUncalibrated.csv").write_text(scaled(-1.0 / 9.80665))
    (folder / "Metadata.csv").write_text(metadata)
    return folder


def android_acc() -> np.ndarray:
    rows = real_lines("TotalAcceleration.csv")[1:]
    return np.array([[float(a) for a in line.split(",")[2:]] for line in rows])[:, ::-1]  # z, y, x


SETTINGS = settings(
    max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(
    delimiter=st.sampled_from([",", ";"]),
    acc_files=st.sampled_from(["user+gravity", "uncalibrated"]),
    crlf=st.booleans(),
)
def test_an_ios_export_from_before_the_setting_reads_its_accelerometer_in_androids_axes(
    tmp_path, delimiter, acc_files, crlf
):
    """No ``standardisation`` column: iOS's own frames, negated to Android's, the note saying which it
    assumed and why."""
    end = "\r\n" if crlf else "\n"
    metadata = delimiter.join(OLD_HEADER) + end + delimiter.join(OLD_ROW) + end
    folder = ios_export(Path(tempfile.mkdtemp(dir=tmp_path)) / "rec", metadata, acc_files)
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[SensorKind.ACC].xyz, android_acc(), rtol=1e-9, atol=1e-9)
    said = [note for note in log.notes if "iOS export" in note]
    assert len(said) == 1 and "before app version 1.29" in said[0] and "negated" in said[0], said


def test_hil_replay_says_which_frames_it_assumed(tmp_path):
    metadata = ",".join(OLD_HEADER) + "\n" + ",".join(OLD_ROW) + "\n"
    folder = ios_export(tmp_path / "rec", metadata, "user+gravity")
    out = tmp_path / "run"
    assert main(["replay", str(folder), "--out", str(out), "--no-plots"]) == 0
    notes = json.loads((out / "summary.json").read_text())["reader_notes"]
    assert any("before app version 1.29" in n and "negated" in n for n in notes), notes


@SETTINGS
@given(value=st.sampled_from(["", "maybe", "unknown", "2", "ja", "-"]))
def test_a_standardisation_neither_on_nor_off_is_an_error_naming_metadata_csv(tmp_path, value):
    header = (*OLD_HEADER, "standardisation")
    metadata = ",".join(header) + "\n" + ",".join((*OLD_ROW, value)) + "\n"
    folder = ios_export(Path(tempfile.mkdtemp(dir=tmp_path)) / "rec", metadata, "user+gravity")
    with pytest.raises(InputFormatError, match="neither on") as raised:
        read_log(folder)
    assert "Metadata.csv" in str(raised.value)

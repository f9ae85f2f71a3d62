"""An iOS Sensor Logger export recorded with "Standardise Units & Frames" off — the app's default
(github.com/tszheichoi/awesome-sensor-logger, CROSSPLATFORM.md and UNITS.md) — holds the acceleration
and gravity with every axis the other way round from Android's (flat, screen up: gravity -z, where
Android's specific force reads +z), and ``Metadata.csv`` says so (``platform`` ios, ``standardisation``
false). It was read as if the setting were on, only a note saying so: the accelerometer upside down, the
estimator's attitude flipped with no warning. Now its axes are negated to Android's, noted.

The exports are built from the real Android export (iOS writes no ``TotalAcceleration.csv``: its
accelerometer is ``Accelerometer.csv`` plus ``Gravity.csv``, or the raw ``AccelerometerUncalibrated.csv``
in g), each file written as the iOS app would write it."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_lines

from hil.estimation.sensors import SensorKind
from hil.logs import read_log

pytestmark = needs_real_export

G = 9.80665
METADATA_HEADER = (
    "version", "device name", "recording epoch time", "recording time", "recording timezone", "platform",
    "appVersion", "device id", "sensors", "sampleRateMs", "standardisation", "platform version",
)  # fmt: skip
"""The app's ``Metadata.csv`` columns (schema version 3)."""


def _metadata(platform: str, standardisation: str, delimiter: str) -> str:
    row = ("3", "iPhone", "1679068247375", "2023-03-17_15-50-47", "Europe/London", platform, "1.40",
           "abc", "Accelerometer|Gravity|Gyroscope|Magnetometer", "10|10|10|10", standardisation,
           "17.3")  # fmt: skip
    return delimiter.join(METADATA_HEADER) + "\n" + delimiter.join(row) + "\n"


def _rows(lines: list[str], scale: float) -> list[str]:
    """The real TotalAcceleration.csv's rows with the axes multiplied by ``scale``."""
    out = [lines[0]]
    for line in lines[1:]:
        time, elapsed, *axes = line.split(",")
        out.append(",".join([time, elapsed, *(repr(float(a) * scale) for a in axes)]))
    return out


def _ios_export(folder, sign: float, acc_files: str, metadata: str):
    """The real export as iOS writes it: the acceleration's axes times ``sign`` (-1: iOS's own frame)."""
    folder.mkdir()
    for name in ("Gyroscope.csv", "Magnetometer.csv"):
        (folder / name).write_text("\n".join(real_lines(name)) + "\n")
    total = real_lines("TotalAcceleration.csv")
    if acc_files == "user+gravity":  # iOS's calibrated accelerometer: the user acceleration and gravity
        (folder / "Gravity.csv").write_text("\n".join(_rows(total, sign)) + "\n")
        (folder / "Accelerometer.csv").write_text("\n".join(_rows(total, 0.0)) + "\n")
    else:  # the raw accelerometer, in g without the setting
        (folder / "AccelerometerUncalibrated.csv").write_text("\n".join(_rows(total, sign / G)) + "\n")
    (folder / "Metadata.csv").write_text(metadata)
    return folder


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    standardised=st.booleans(),
    written=st.sampled_from([("false", "true"), ("FALSE", "TRUE"), ("0", "1")]),
    delimiter=st.sampled_from([",", ";"]),
    acc_files=st.sampled_from(["user+gravity", "uncalibrated"]),
)
def test_an_ios_export_without_standardised_frames_reads_its_accelerometer_in_androids_axes(
    tmp_path_factory, standardised, written, delimiter, acc_files
):
    """Whichever way the setting was, the accelerometer comes out as Android's: gravity up the screen's
    normal when the phone lies screen up, the same samples the Android export gives."""
    off, on = written
    metadata = _metadata("iOS", on if standardised else off, delimiter)
    folder = _ios_export(tmp_path_factory.mktemp("ios") / "rec", 1.0 if standardised else -1.0, acc_files,
                         metadata)  # fmt: skip
    log = read_log(folder)
    android = np.array(
        [[float(a) for a in line.split(",")[2:]] for line in real_lines("TotalAcceleration.csv")[1:]]
    )
    np.testing.assert_allclose(log.streams[SensorKind.ACC].xyz, android[:, ::-1], rtol=1e-9, atol=1e-9)
    said = [note for note in log.notes if "iOS export" in note]
    assert len(said) == 1 and ("negated" in said[0]) == (not standardised), said


def test_an_android_export_saying_standardisation_false_is_read_as_it_is(tmp_path):
    """The setting changes nothing on Android: its frames are the standard ones."""
    folder = _ios_export(tmp_path / "rec", 1.0, "user+gravity", _metadata("android", "false", ","))
    log = read_log(folder)
    assert log.streams[SensorKind.ACC].xyz[0, 2] > 0 and not any("negated" in n for n in log.notes)

"""A Sensor Logger export whose preferred file for a sensor holds no sample — 0 bytes, or a header only:
the app's file for a sensor the phone lacks or never started — beside another file of that sensor that
holds its readings (``Magnetometer.csv`` header-only beside ``MagnetometerUncalibrated.csv``,
``Gyroscope.csv`` beside ``GyroscopeUncalibrated.csv``, ``TotalAcceleration.csv`` beside
``Accelerometer.csv`` + ``Gravity.csv`` or ``AccelerometerUncalibrated.csv``). The preferred file was
taken whatever it held: a magnetometer of thousands of readings was dropped and the log read 6-axis
(heading "not observed"), and an empty gyroscope or accelerometer file refused an export that held the
sensor. Now the next file of the sensor is read, and the empty one is noted as passed over. Built from
the shared real export (written to tmp_path), folder or zip."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_export, real_lines

from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

pytestmark = needs_real_export

HEADER = "time,seconds_elapsed,z,y,x"
EMPTY = {"0 bytes": "", "header only": HEADER + "\n", "header and blank lines": HEADER + "\n\n  \n"}
# the preferred file emptied, and the file(s) of the same sensor that hold its readings instead
CASES = {
    "Magnetometer.csv": ("MagnetometerUncalibrated.csv",),
    "Gyroscope.csv": ("GyroscopeUncalibrated.csv",),
    "TotalAcceleration.csv": ("AccelerometerUncalibrated.csv",),
}
KIND = {
    "Magnetometer.csv": SensorKind.MAG,
    "Gyroscope.csv": SensorKind.GYR,
    "TotalAcceleration.csv": SensorKind.ACC,
}


def _export(root: Path, emptied: str, empty: str, zipped: bool) -> Path:
    """The real export with ``emptied`` holding ``empty`` and its readings in its fallback file."""
    folder = real_export(root / "Recording")
    (folder / CASES[emptied][0]).write_text((folder / emptied).read_text())
    (folder / emptied).write_text(empty)
    if not zipped:
        return folder
    archive = root / "Recording.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.iterdir()):
            z.write(f, f"Recording/{f.name}")
    return archive


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(emptied=st.sampled_from(sorted(CASES)), empty=st.sampled_from(sorted(EMPTY)), zipped=st.booleans())
def test_an_empty_preferred_file_gives_way_to_the_sensors_other_file(
    tmp_path_factory, emptied, empty, zipped
):
    """Every sensor is read, sample for sample as in the export; the empty file is noted as passed over."""
    reference = read_log(real_export(tmp_path_factory.mktemp("ref") / "Recording"))
    log = read_log(_export(tmp_path_factory.mktemp("exp"), emptied, EMPTY[empty], zipped))
    assert set(log.streams) == set(reference.streams)
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].t, stream.t)
        np.testing.assert_allclose(log.streams[kind].xyz, stream.xyz, rtol=1e-12)
    assert any(n.startswith(emptied) and "passed over" in n for n in log.notes), log.notes
    assert any(CASES[emptied][0] in n for n in log.notes)


def test_an_empty_total_acceleration_gives_way_to_user_acceleration_and_gravity(tmp_path):
    """``TotalAcceleration.csv`` a header only, ``Accelerometer.csv`` (gravity removed) + ``Gravity.csv``
    holding the readings: their sum is read (it was refused, "no samples")."""
    folder = real_export(tmp_path / "Recording")
    total = real_lines("TotalAcceleration.csv")
    (folder / "Gravity.csv").write_text("\n".join(total) + "\n")
    zero = [total[0]] + [",".join([*line.split(",")[:2], "0", "0", "0"]) for line in total[1:]]
    (folder / "Accelerometer.csv").write_text("\n".join(zero) + "\n")
    (folder / "TotalAcceleration.csv").write_text(HEADER + "\n")
    reference = read_log(real_export(tmp_path / "reference"))
    log = read_log(folder)
    np.testing.assert_allclose(
        log.streams[SensorKind.ACC].xyz, reference.streams[SensorKind.ACC].xyz, rtol=1e-12
    )
    assert any("Accelerometer.csv (user acceleration) + Gravity.csv" in n for n in log.notes)


@pytest.mark.parametrize("emptied", ["Gyroscope.csv", "TotalAcceleration.csv"])
def test_every_file_of_a_needed_sensor_empty_is_an_error_naming_the_first(tmp_path, emptied):
    folder = real_export(tmp_path / "Recording")
    (folder / CASES[emptied][0]).write_text(HEADER + "\n")
    (folder / emptied).write_text(HEADER + "\n")
    with pytest.raises(InputFormatError, match="no samples") as err:
        read_log(folder)
    assert str(folder / emptied) in str(err.value)


def test_every_magnetometer_file_empty_is_a_6_axis_log(tmp_path):
    folder = real_export(tmp_path / "Recording")
    (folder / "MagnetometerUncalibrated.csv").write_text("")
    (folder / "Magnetometer.csv").write_text(HEADER + "\n")
    log = read_log(folder)
    assert log.six_axis and any("6-axis" in n for n in log.notes)

"""A Sensor Logger export whose only accelerometer file is ``Gravity.csv`` is refused naming it and what is
missing, through ``hil replay`` (and the JSON export's reader, which shares the choosing).

Before: "no accelerometer file (TotalAcceleration.csv, Accelerometer.csv + Gravity.csv, or
AccelerometerUncalibrated.csv)" at the export's folder — never saying a Gravity.csv had been found, nor
that it cannot stand in for an accelerometer (it is the phone's gravity estimate, low-pass filtered and
fused with its gyroscope: it holds still through the motion an accelerometer measures). The real export's
``TotalAcceleration.csv`` rows are written as ``Gravity.csv`` (the header is the app's for that file too),
whole, zipped or gzipped.
"""

from __future__ import annotations

import gzip
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from hil.logs import read_log
from hil.logs.sensorlogger import GRAVITY_ALONE
from protocol.errors import InputFormatError
from tests.log_support import needs_real_export, real_lines

pytestmark = needs_real_export


def _gravity_only(folder: Path, how: str) -> Path:
    """An export of the real recording's gyroscope and magnetometer, and its acceleration as
    ``Gravity.csv`` only: as a folder, a zip of it, or a folder of gzipped files."""
    folder.mkdir(parents=True)
    texts = {
        "Gyroscope.csv": real_lines("Gyroscope.csv"),
        "Magnetometer.csv": real_lines("Magnetometer.csv"),
        "Gravity.csv": real_lines("TotalAcceleration.csv"),
    }
    data = {name: ("\n".join(lines) + "\n").encode() for name, lines in texts.items()}
    if how == "zip":
        path = folder / "export.zip"
        with zipfile.ZipFile(path, "w") as z:
            for name, body in data.items():
                z.writestr(name, body)
        return path
    for name, body in data.items():
        if how == "gz":
            (folder / f"{name}.gz").write_bytes(gzip.compress(body))
        else:
            (folder / name).write_bytes(body)
    return folder


@pytest.mark.parametrize("how", ["folder", "zip", "gz"])
def test_gravity_alone_is_named_and_why_it_cannot_stand_in(tmp_path: Path, how: str) -> None:
    export = _gravity_only(tmp_path / "export", how)
    with pytest.raises(InputFormatError) as caught:
        read_log(export)
    said = str(caught.value)
    assert said.startswith(str(export)) and "Gravity.csv" in said.split(": ")[0], said  # where: the file
    assert "cannot stand in" in said and "filtered" in said, said  # and why it is not read
    assert "TotalAcceleration.csv" in said, said  # what is missing
    assert said.endswith(GRAVITY_ALONE), said


def test_hil_replay_says_what_is_missing(tmp_path: Path) -> None:
    export = _gravity_only(tmp_path / "export", "folder")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(export), "--no-plots", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    assert "Traceback" not in done.stderr, done.stderr
    assert str(export / "Gravity.csv") in done.stderr, done.stderr
    assert "cannot stand in" in done.stderr and "missing: TotalAcceleration.csv" in done.stderr, done.stderr
    assert not (tmp_path / "out" / "estimates.csv").exists()

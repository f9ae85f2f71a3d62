"""Phone exports laid out a little differently from the app's own, each once read wrongly or without a word.

- phyphox: a 0-byte sensor file (a copy or sync cut short). ``Gyroscope.csv`` of 0 bytes was refused as
  "no gyroscope file (found Accelerometer.csv …)", the file that is there never named, and a 0-byte
  ``Magnetometer.csv`` noted as "no magnetometer file". Now "Gyroscope.csv is empty", as Sensor Logger's
  reader says it, naming the file.
- Sensor Logger: ``Metadata.csv``'s ``platform`` other than one starting ``ios`` (``iPadOS``, ``""``,
  ``windows``) was read as Android's frames with no word: an iPadOS recording with "Standardise Units &
  Frames" off replayed upside down. Now a version or spelling is read and noted, an empty one noted as
  unstated, and any other refused naming ``Metadata.csv``.
- Sensor Logger: a ``Metadata.csv`` at the top beside the recording's folder (``Rec/Gyroscope.csv``) was
  dropped without a word: an iOS recording replayed in Android's frames. Now it is the recording's
  metadata, noted; one that is no recording's (beside a recording with its own) is said to be unread.

Built from the real Android export (read, never copied) and the phyphox helpers of the neighbouring tests.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_export
from test_logs_beside_hunt6b_phyphox_pause import FILES, paused_experiment

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
SETTINGS = settings(
    max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
IOS_OFF = "version,platform,standardisation\n3,{platform},false\n"
"""A ``Metadata.csv`` of a recording with "Standardise Units & Frames" off: iOS's own frames if iOS."""


def _experiment(root: Path) -> Path:
    """An unpaused phyphox experiment export (no meta/time.csv)."""
    folder = paused_experiment(root / "Experiment", 1.0, 0.0)
    shutil.rmtree(folder / "meta")
    return folder


def _zipped(folder: Path) -> Path:
    archive = folder.with_suffix(".zip")
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    return archive


# --- phyphox: a 0-byte sensor file is named as empty ---------------------------------------------------


@SETTINGS
@given(
    kind=st.sampled_from([GYR, ACC]),
    blank=st.sampled_from(["", "\n", "\r\n\r\n", "  \n"]),
    zipped=st.booleans(),
)
def test_an_empty_phyphox_gyroscope_or_accelerometer_is_an_error_naming_the_empty_file(
    tmp_path_factory, kind, blank, zipped
):
    folder = _experiment(tmp_path_factory.mktemp("exp"))
    (folder / FILES[kind]).write_text(blank)
    path = _zipped(folder) if zipped else folder
    with pytest.raises(InputFormatError) as raised:
        read_log(path)
    message = str(raised.value)
    assert f"{FILES[kind]} is empty" in message, message
    assert message.split(": ")[0].endswith(FILES[kind]), message  # where: the empty file itself


@pytest.mark.parametrize("zipped", [False, True])
def test_an_empty_phyphox_magnetometer_is_a_6_axis_log_naming_the_empty_file(tmp_path, zipped):
    folder = _experiment(tmp_path)
    (folder / FILES[MAG]).write_bytes(b"")
    log = read_log(_zipped(folder) if zipped else folder)
    assert log.six_axis and set(log.streams) == {GYR, ACC}
    said = [n for n in log.notes if "6-axis" in n]
    assert said and all("Magnetometer.csv is empty" in n for n in said), log.notes


def test_hil_replay_of_an_empty_phyphox_gyroscope_names_it_and_fails_cleanly(tmp_path, capsys):
    folder = _experiment(tmp_path)
    (folder / FILES[GYR]).write_bytes(b"")
    assert main(["replay", str(folder), "--out", str(tmp_path / "out"), "--no-plots"]) != 0
    err = capsys.readouterr().err
    assert "Gyroscope.csv is empty" in err and "Traceback" not in err


# --- Sensor Logger: Metadata.csv's platform --------------------------------------------------------------


def _platform_export(root: Path, platform: str) -> Path:
    folder = real_export(root / "rec")
    (folder / "Metadata.csv").write_text(IOS_OFF.format(platform=platform))
    return folder


@needs_real_export
@SETTINGS
@given(
    family=st.sampled_from(["ios", "ipados", "iPhone OS", "android"]),
    case=st.sampled_from([str.lower, str.upper, str.title]),
    version=st.sampled_from(["", " 17", "_17.2", "-14", " 17.2.1 (21C66)", " v13"]),
)
def test_a_platform_with_a_version_or_another_spelling_is_read_as_its_family_and_noted(
    tmp_path_factory, family, case, version
):
    root = tmp_path_factory.mktemp("plat")
    reference = read_log(_platform_export(root / "ref", "ios" if family != "android" else "android"))
    value = case(family) + version
    log = read_log(_platform_export(root / "odd", value))
    for kind in (GYR, ACC, MAG):
        np.testing.assert_array_equal(log.streams[kind].xyz, reference.streams[kind].xyz)
    if value.lower() not in ("ios", "android"):
        assert any("platform" in n and "read as" in n for n in log.notes), log.notes


@needs_real_export
@pytest.mark.parametrize("platform", ["windows", "linux", "web", "unknown", "ios android"])
def test_a_platform_neither_ios_nor_android_is_an_error_naming_metadata_csv(tmp_path, platform):
    folder = _platform_export(tmp_path, platform)
    with pytest.raises(InputFormatError, match="neither iOS nor Android") as raised:
        read_log(folder)
    assert str(folder / "Metadata.csv") in str(raised.value)


@needs_real_export
def test_an_empty_platform_is_noted_as_unstated(tmp_path):
    log = read_log(_platform_export(tmp_path, ""))
    reference = read_log(real_export(tmp_path / "ref"))
    np.testing.assert_array_equal(log.streams[ACC].xyz, reference.streams[ACC].xyz)
    assert any("'platform' is empty" in n for n in log.notes), log.notes


@needs_real_export
def test_a_json_export_with_an_ipados_platform_is_read_in_ios_frames(tmp_path):
    """The JSON export's ``Metadata`` record goes through the same rule (one for both exports)."""
    folder = _platform_export(tmp_path, "ios")
    csv_log = read_log(folder)
    records = [{"sensor": "Metadata", "platform": "iPadOS 17", "standardisation": "false"}]
    for name, sensor in (("Gyroscope.csv", "Gyroscope"), ("TotalAcceleration.csv", "TotalAcceleration"),
                         ("Magnetometer.csv", "Magnetometer")):  # fmt: skip
        lines = (folder / name).read_text().splitlines()
        head = lines[0].split(",")
        records += [{"sensor": sensor, **dict(zip(head, line.split(","), strict=True))} for line in lines[1:]]
    path = tmp_path / "rec.json"
    path.write_text(json.dumps(records))
    log = read_log(path)
    np.testing.assert_allclose(log.streams[ACC].xyz, csv_log.streams[ACC].xyz)


# --- Sensor Logger: a Metadata.csv above the recording's folder ------------------------------------------


@needs_real_export
@SETTINGS
@given(depth=st.sampled_from(["Rec", "Rec/inner"]), zipped=st.booleans())
def test_a_metadata_csv_above_the_recordings_folder_is_its_metadata_and_noted(
    tmp_path_factory, depth, zipped
):
    root = tmp_path_factory.mktemp("above")
    beside = real_export(root / "beside")
    (beside / "Metadata.csv").write_text(IOS_OFF.format(platform="ios"))
    reference = read_log(beside)  # iOS's frames: the accelerometer negated
    top = root / "top"
    real_export(top / depth)
    (top / "Metadata.csv").write_text(IOS_OFF.format(platform="ios"))
    log = read_log(_zipped(top) if zipped else top)
    np.testing.assert_array_equal(log.streams[ACC].xyz, reference.streams[ACC].xyz)
    assert any("read from above its sensor files" in n for n in log.notes), log.notes


@needs_real_export
def test_a_metadata_csv_no_recordings_own_is_said_to_be_unread(tmp_path):
    top = tmp_path / "top"
    folder = real_export(top / "Rec")
    (folder / "Metadata.csv").write_text(IOS_OFF.format(platform="android"))
    (top / "Metadata.csv").write_text(IOS_OFF.format(platform="ios"))
    log = read_log(top)
    assert any("not read" in n and str(top / "Metadata.csv") in n for n in log.notes), log.notes
    beside = tmp_path / "sibling"
    real_export(beside / "Rec")
    (beside / "Other").mkdir()
    (beside / "Other" / "Metadata.csv").write_text(IOS_OFF.format(platform="ios"))
    log = read_log(beside)
    assert any("not read" in n and "Other" in n for n in log.notes), log.notes

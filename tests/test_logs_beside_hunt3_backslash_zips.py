"""A zip made on Windows by a tool that breaks the zip format's rule of '/' between folders — .NET
Framework 4.5's ``ZipFile.CreateFromDirectory``, PowerShell 5's ``Compress-Archive`` — names its entries
``Recording\\Gyroscope.csv``. ``unzip`` and 7-Zip read that as a folder and its file; Python keeps it as one
name with a backslash in it, and an export zipped a folder deep that way was "not a recognised log"
(status 2). It now reads as the export, in every format, at any depth, inside another zip too.

The archives are built in tmp_path from the real recordings."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import REAL_FILES, assert_same_samples, needs_real_export, real_export

from hil.cli import main
from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA

TYREX_TRIAL = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Texting"
TYREX_FILES = ("accelerometer.txt.gz", "gyroscope-calibrated.txt.gz", "magnetometer-calibrated.txt.gz")


def _windows_zip(files: dict[str, bytes], folders: list[str], directory_entries: bool) -> bytes:
    """A zip of ``files`` under ``folders``, every path joined with backslashes (and, as .NET writes
    them, an entry for each folder, ``Recording\\``)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        if directory_entries:
            for depth in range(1, len(folders) + 1):
                z.writestr("\\".join(folders[:depth]) + "\\", b"")
        for name, data in files.items():
            z.writestr("\\".join([*folders, name]), data)
    return out.getvalue()


FOLDER_NAMES = st.lists(st.sampled_from(["Recording", "2023-03-17_15-50-47", "Aufnahme ü", "录音"]),
                        min_size=1, max_size=2, unique=True)  # fmt: skip


@needs_real_export
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(folders=FOLDER_NAMES, directory_entries=st.booleans(), nested=st.booleans())
def test_a_sensor_logger_export_zipped_with_backslashes_reads_as_the_export(
    tmp_path_factory, folders, directory_entries, nested
):
    """``nested``: the Windows zip mailed inside another zip (made the same way)."""
    export = real_export(tmp_path_factory.mktemp("plain") / "rec")
    files = {name: (export / name).read_bytes() for name in REAL_FILES}
    data = _windows_zip(files, folders, directory_entries)
    if nested:
        data = _windows_zip({"Recording.zip": data}, ["Mail"], directory_entries)
    archive = tmp_path_factory.mktemp("zipped") / "Recording.zip"
    archive.write_bytes(data)
    assert_same_samples(read_log(archive), read_log(export))


@pytest.mark.skipif(not TYREX_TRIAL.is_dir(), reason="the shared tyrex trial is not here")
def test_a_tyrex_trial_zipped_with_backslashes_replays_as_the_trial(tmp_path):
    """Through ``hil replay``: the trial's files two folders deep, the truth beside them."""
    files = {
        name: (TYREX_TRIAL / name).read_bytes()
        for name in (*TYREX_FILES, "qualisys.mat", "timeAlignment.txt")
    }
    archive = tmp_path / f"{TYREX_TRIAL.name}.zip"
    archive.write_bytes(_windows_zip(files, ["tyrex", TYREX_TRIAL.name], True))
    log = read_log(archive)
    reference = read_log(TYREX_TRIAL)
    assert log.format == "tyrex" and log.truth is not None
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz)
    assert (
        main(["replay", str(archive), "--out", str(tmp_path / "out"), "--window", "0", "8", "--no-plots"])
        == 0
    )

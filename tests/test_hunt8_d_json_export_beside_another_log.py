"""A Sensor Logger JSON export beside a log of another format (one folder or zip) is two logs side by
side: refused naming the JSON export, as two recordings of one format are, and ``--format`` chooses.

Before: the log told first was read and the other passed over without a word — exit 0, whichever
recording it held: the recording's CSV files beside a ``.json`` export (the JSON passed over), a zip of a
phyphox export and a ``.json`` export (the phyphox export passed over). Now detection refuses, naming
the JSON export and the other format, and ``--format`` reads either. Built from the real Android export
(read, never copied)."""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples, needs_real_export
from test_hunt8_d_json_metadata import write_csv_export, write_json_export
from test_hunt8_d_phyphox_two_experiments import experiment

from hil.cli import main
from hil.logs import detect_format, read_log
from protocol.errors import InputFormatError

pytestmark = needs_real_export


def beside(folder: Path, other: str) -> None:
    """``folder`` holding a log of format ``other`` and, beside it, a Sensor Logger JSON export."""
    if other == "sensorlogger":
        write_csv_export(folder, None)
    else:
        folder.mkdir(parents=True)
        for name, data in experiment(("Accelerometer.csv", "Gyroscope.csv"), 1_714_550_400.0).items():
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_bytes(data)
    write_json_export(folder / "Recording 2024-05-01.json", [], 0)


def packed(folder: Path, packing: str) -> Path:
    if packing == "folder":
        return folder
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    path = folder.with_suffix(".zip")
    path.write_bytes(buffer.getvalue())
    return path


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(other=st.sampled_from(["sensorlogger", "phyphox"]), packing=st.sampled_from(["folder", "zip"]))
def test_a_json_export_beside_another_log_is_refused_naming_it(tmp_path, other, packing):
    folder = Path(tempfile.mkdtemp(dir=tmp_path)) / "rec"
    beside(folder, other)
    path = packed(folder, packing)
    for look in (detect_format, read_log):
        with pytest.raises(InputFormatError, match="side by side|logs of different formats") as raised:
            look(path)
        assert "Recording 2024-05-01.json" in str(raised.value) and other in str(raised.value)


def test_hil_replay_refuses_and_format_chooses_either(tmp_path, capsys):
    folder = tmp_path / "rec"
    beside(folder, "sensorlogger")
    assert main(["replay", str(folder), "--out", str(tmp_path / "run"), "--no-plots"]) != 0
    assert "side by side" in capsys.readouterr().err
    assert_same_samples(read_log(folder, "sensorlogger-json"), read_log(folder, "sensorlogger"))
    assert read_log(folder / "Recording 2024-05-01.json").format == "sensorlogger-json"

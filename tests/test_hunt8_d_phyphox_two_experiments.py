"""Two phyphox experiments in one archive or folder are refused, as Sensor Logger recordings side by side
are: a typed error naming the archive and both experiments.

Before: the first experiment's (by name) accelerometer and gyroscope were read and the second's noted as
"a second … file, ignored" — exit 0, one recording replayed and the other passed over, where the same
archive of two Sensor Logger recordings is an error. Worse, when only the second held a magnetometer, its
readings were joined to the first recording's motion. Single-sensor exports side by side (each a sensor
the others lack) are still one recording's, joined by their ``meta/time.csv``."""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from hil.logs import read_log
from protocol.errors import InputFormatError

HEADS = {
    name: ("Time (s)", *(f"{label} {axis} ({unit})" for axis in "xyz"))
    for name, label, unit in (
        ("Accelerometer.csv", "Acceleration", "m/s^2"),
        ("Gyroscope.csv", "Gyroscope", "rad/s"),
        ("Magnetometer.csv", "Magnetic field", "µT"),
    )
}
VALUES = {"Accelerometer.csv": (0.1, 0.2, 9.8), "Gyroscope.csv": (0.01, -0.02, 0.03),
          "Magnetometer.csv": (20.0, 0.0, -40.0)}  # fmt: skip


def experiment(sensors: tuple[str, ...], start_s: float, rows: int = 200) -> dict[str, bytes]:
    """One multi-sensor experiment's export: its tables at 100 Hz from 0, and meta/time.csv."""
    files = {}
    t = np.arange(rows) * 0.01
    for name in sensors:
        lines = [",".join(f'"{h}"' for h in HEADS[name])]
        lines += [",".join(f"{v:.9E}" for v in (ti, *VALUES[name])) for ti in t]
        files[name] = ("\n".join(lines) + "\n").encode()
    files["meta/time.csv"] = (
        '"event","experiment time","system time","system time text"\n'
        f'"START",0.000000000E0,{start_s:.3f},"2024-05-01 10:00:00.000 UTC"\n'
    ).encode()
    return files


def zipped(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buffer.getvalue()


def lay_out(root: Path, exports: dict[str, dict[str, bytes]], packing: str) -> Path:
    """The exports as users bring them: folders, one zip of folders, a zip of each export's zip."""
    members = {f"{folder}/{name}": data for folder, files in exports.items() for name, data in files.items()}
    if packing == "folder":
        for name, data in members.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data)
        return root
    if packing == "zip":
        (root.parent / "two.zip").write_bytes(zipped(members))
        return root.parent / "two.zip"
    outer = {f"{folder}.zip": zipped(files) for folder, files in exports.items()}
    (root.parent / "nested.zip").write_bytes(zipped(outer))
    return root.parent / "nested.zip"


SENSOR_SETS = st.sampled_from(
    [("Accelerometer.csv", "Gyroscope.csv"), ("Accelerometer.csv", "Gyroscope.csv", "Magnetometer.csv")]
)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    first=SENSOR_SETS,
    second=st.sampled_from(
        [
            ("Accelerometer.csv", "Gyroscope.csv", "Magnetometer.csv"),
            ("Gyroscope.csv",),
            ("Accelerometer.csv",),
        ]
    ),
    packing=st.sampled_from(["folder", "zip", "nested zip"]),
    names=st.sampled_from(
        [("Experiment A", "Experiment B"), ("run 2024-05-01 10-00", "run 2024-05-01 11-00")]
    ),
)
def test_two_experiments_that_share_a_sensor_are_refused_naming_both(tmp_path, first, second, packing, names):
    work = Path(tempfile.mkdtemp(dir=tmp_path)) / "exports"
    work.mkdir()
    log_path = lay_out(
        work,
        {names[0]: experiment(first, 1_714_550_400.0), names[1]: experiment(second, 1_714_554_000.0)},
        packing,
    )
    with pytest.raises(InputFormatError, match="side by side") as raised:
        read_log(log_path)
    said = str(raised.value)
    assert names[0] in said and names[1] in said and log_path.name in said, said


def test_hil_replay_of_two_experiments_exits_with_the_error_not_a_run(tmp_path, capsys):
    exports = {
        "Experiment A": experiment(("Accelerometer.csv", "Gyroscope.csv"), 1_714_550_400.0),
        "Experiment B": experiment(tuple(HEADS), 1_714_554_000.0),
    }
    path = lay_out(tmp_path / "x", exports, "zip")
    code = main(["replay", str(path), "--out", str(tmp_path / "run"), "--no-plots"])
    assert code != 0
    assert "side by side" in capsys.readouterr().err
    assert not (tmp_path / "run" / "summary.json").exists()


def test_single_sensor_exports_side_by_side_are_still_one_recording(tmp_path):
    exports = {
        "Acceleration with g": experiment(("Accelerometer.csv",), 1_714_550_400.0),
        "Gyroscope": experiment(("Gyroscope.csv",), 1_714_550_400.25),
        "Magnetometer": experiment(("Magnetometer.csv",), 1_714_550_400.5),
    }
    log = read_log(lay_out(tmp_path / "x", exports, "zip"))
    assert len(log.streams) == 3

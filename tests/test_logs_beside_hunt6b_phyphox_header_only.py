"""A phyphox experiment export whose ``Magnetometer.csv`` holds its header only (the phone has no
magnetometer, or it never started) was refused, "log has an empty MAG stream", naming the folder — where
Sensor Logger's header-only ``Magnetometer.csv`` is a 6-axis log — and a header-only gyroscope or
accelerometer file was "log has no GYR samples", naming no file. Now a header-only magnetometer is a
6-axis log, noted, and a header-only gyroscope or accelerometer an error naming its file."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_logs_beside_hunt6b_phyphox_pause import FILES, paused_experiment
from test_phone_exports import motion

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG


def _experiment(root, delimiter=",", decimal=".", n=400):
    """An unpaused experiment export (no meta/time.csv) with its magnetometer a header only."""
    folder = paused_experiment(root / "Experiment", 1.0, 0.0, n=n, delimiter=delimiter, decimal=decimal)
    shutil.rmtree(folder / "meta")
    return folder


def _header_only(path) -> None:
    path.write_text(path.read_text().splitlines()[0] + "\n")


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(dialect=st.sampled_from([(",", "."), (";", ","), ("\t", "."), ("\t", ",")]))
def test_a_header_only_magnetometer_is_a_6_axis_log(tmp_path_factory, dialect):
    folder = _experiment(tmp_path_factory.mktemp("exp"), *dialect)
    _header_only(folder / FILES[MAG])
    log = read_log(folder)
    assert log.six_axis and set(log.streams) == {GYR, ACC}
    np.testing.assert_allclose(log.streams[GYR].t, motion()[0], atol=1e-9)
    assert any("Magnetometer.csv has no samples" in n and "6-axis" in n for n in log.notes)


def test_hil_replay_of_a_header_only_magnetometer_reports_heading_not_observed(tmp_path):
    folder = _experiment(tmp_path, n=1000)
    _header_only(folder / FILES[MAG])
    out = tmp_path / "out"
    assert main(["replay", str(folder), "--out", str(out), "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["heading"].startswith("not observed")


@pytest.mark.parametrize("kind", [GYR, ACC])
def test_a_header_only_gyroscope_or_accelerometer_is_an_error_naming_its_file(tmp_path, kind):
    folder = _experiment(tmp_path)
    _header_only(folder / FILES[kind])
    with pytest.raises(InputFormatError, match="no samples") as err:
        read_log(folder)
    assert str(folder / FILES[kind]) in str(err.value)

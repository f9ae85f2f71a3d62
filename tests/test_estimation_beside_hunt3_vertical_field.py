"""A magnetic field measured, or given, vertical: parallel to gravity, it gives no heading.

A log whose magnetometer reads along gravity over its first seconds (a magnet or steel under the phone),
replayed with the default preset, and ``--inclination ±90 --preset paper``, were both refused with
``hil replay: error: E: inertial directions are parallel: their cross product is undefined`` — a
ConfigError naming ``E``, an internal matrix the user never gave, not the log or the option at fault.
Now the measured case is an InputFormatError naming the log and what to give instead, and the given one
names the paper preset and why.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs import project_csv, read_log

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


def _replay(log: Path, out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(log), "--out", str(out), "--no-plots", *args],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip


@settings(
    max_examples=3,
    deadline=None,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),  # each example a replay's subprocess: no shrinking
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(sign=st.sampled_from([1.0, -1.0]), strength_uT=st.floats(1.0, 500.0))
def test_a_log_whose_magnetometer_reads_along_gravity_is_refused_naming_the_log(
    tmp_path_factory, sign, strength_uT
):
    """The magnetometer's every reading along the accelerometer's nearest one (up or down, any strength):
    the error names the log file and says the field is vertical, exit status 2, no traceback."""
    folder = tmp_path_factory.mktemp("vertical")
    log = read_log(FIXTURE)
    acc, mag = log.streams[SensorKind.ACC], log.streams[SensorKind.MAG]
    nearest = np.clip(np.searchsorted(acc.t, mag.t), 0, len(acc) - 1)
    along = acc.xyz[nearest] / np.linalg.norm(acc.xyz[nearest], axis=1, keepdims=True)
    streams = {**log.streams, SensorKind.MAG: SensorStream(SensorKind.MAG, mag.t, sign * strength_uT * along)}
    path = project_csv.write(SensorLog(streams, "vertical", "csv", log.truth), folder / "vertical.csv")
    run = _replay(path, folder / "out")
    assert run.returncode == 2, run.stdout + run.stderr
    assert f"{path}: its magnetometer measures a vertical field" in run.stderr, run.stderr
    assert "E: inertial directions" not in run.stderr and "Traceback" not in run.stderr, run.stderr


@pytest.mark.parametrize("inclination", ["90", "-90", "89.99"])
def test_a_vertical_field_given_to_the_paper_preset_is_refused_naming_the_preset(tmp_path, inclination):
    run = _replay(FIXTURE, tmp_path / "out", "--inclination", inclination, "--preset", "paper")
    assert run.returncode == 2, run.stdout + run.stderr
    assert "estimator variational (preset paper): the site's field" in run.stderr, run.stderr
    assert "is vertical" in run.stderr and "E: inertial directions" not in run.stderr, run.stderr


def test_the_default_preset_takes_a_vertical_field_given_as_it_did(tmp_path):
    """The tuned preset uses the field's horizontal part only (its declination): ``--inclination 90`` is
    no contradiction there, and replays."""
    run = _replay(FIXTURE, tmp_path / "out", "--inclination", "90")
    assert run.returncode == 0, run.stdout + run.stderr

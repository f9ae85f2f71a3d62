"""A scenario's phone that reads beyond what the host admits. ``sensors.field_enu_uT`` takes ±1e4 µT an axis
and every ``sensors.*.noise`` / ``bias`` up to 1e3 of the sensor's unit, but the host drops any reading beyond
a phone's range (:class:`hil.estimation.admission.ReadingLimits`: 40 rad/s, ~16 g, 5 mT) as
``out_of_range``. A field of 10 mT had all of a run's magnetometer readings refused — the estimator steered
without heading and the run "completed" — and a gyroscope bias of 50 rad/s every gyroscope reading: the
run ended lost after a 15 s phone gap (in a campaign, every run). Refused as the file is read, naming the
file and the key that puts the phone out of range."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.admission import ReadingLimits
from hil.scenario import load_scenario, scenario_names
from hil.scenario.reader import READING_SIGMAS
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]
LIMITS = ReadingLimits()
AT_REST = {"gyr": 0.0, "acc": 9.81}
"""What each sensor reads at rest in these files (no field written: the magnetometer's is the preset's)."""


def _write(folder: Path, body: str) -> Path:
    path = folder / "phone.toml"
    path.write_text("[scenario]\nname = 'phone'\nduration_s = 3\n" + body)
    return path


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    field=st.tuples(*[st.floats(min_value=-1e4, max_value=1e4)] * 3).filter(
        # not a magnetic pole (a field along gravity gives no heading: refused for that)
        lambda f: math.hypot(*f) > LIMITS.mag and math.hypot(f[0], f[1]) > 0.1 * math.hypot(*f)
    )
)
def test_a_field_beyond_the_magnetometer_range_is_refused_naming_it(tmp_path, field):
    path = _write(tmp_path, f"[sensors]\nfield_enu_uT = [{field[0]!r}, {field[1]!r}, {field[2]!r}]\n")
    with pytest.raises(ConfigError) as caught:
        load_scenario(path)
    assert caught.value.where == "phone.toml: sensors.field_enu_uT"
    assert "out of range" in caught.value.detail


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    kind=st.sampled_from(["gyr", "acc"]),
    figure=st.sampled_from(["noise", "bias"]),
    over=st.floats(min_value=1.001, max_value=1e3),
)
def test_noise_or_bias_reading_beyond_the_sensor_range_is_refused_naming_it(tmp_path, kind, figure, over):
    """A figure whose :data:`READING_SIGMAS` spread, on top of the reading at rest, passes the range."""
    limit = LIMITS.gyr if kind == "gyr" else LIMITS.acc
    value = min(1e3, (limit - AT_REST[kind]) / READING_SIGMAS * over)
    path = _write(tmp_path, f"[sensors]\npreset = 'ideal'\n[sensors.{kind}]\n{figure} = {value!r}\n")
    with pytest.raises(ConfigError) as caught:
        load_scenario(path)
    assert caught.value.where == f"phone.toml: sensors.{kind}.{figure}"
    assert "out of range" in caught.value.detail


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(["gyr", "acc"]), figure=st.sampled_from(["noise", "bias"]))
def test_a_phone_within_its_range_is_taken(tmp_path, kind, figure):
    limit = LIMITS.gyr if kind == "gyr" else LIMITS.acc
    value = (limit - AT_REST[kind]) / READING_SIGMAS * 0.99
    path = _write(tmp_path, f"[sensors]\npreset = 'ideal'\n[sensors.{kind}]\n{figure} = {value!r}\n")
    assert getattr(load_scenario(path).phone, kind).__getattribute__(figure) == value


@pytest.mark.parametrize("name", scenario_names())
def test_the_shipped_scenarios_read_within_range(name):
    load_scenario(name)


@pytest.mark.parametrize(
    ("body", "key"),
    [
        ("[sensors]\nfield_enu_uT = [0.0, 6000.0, -8000.0]\n", "sensors.field_enu_uT"),
        ("[sensors.gyr]\nbias = 50.0\n", "sensors.gyr.bias"),
    ],
)
def test_hil_run_refuses_it_with_exit_2_naming_file_and_key(tmp_path, body, key):
    path = _write(tmp_path, body)
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"phone.toml: {key}" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())

"""``[array]`` keys the chosen geometry does not take, and phone sensors too slow to steer on.

``geometry = "tetrahedron"`` with ``units = 6`` and ``skew_deg = 30`` flew the 3-unit tetrahedron, and a
pyramid's ``gimbal_axes``/``spin_axes`` were dropped: each key a geometry does not take was ignored,
unsaid. Now each is a ConfigError naming the key, the geometry and the keys it takes. A gyroscope or an
accelerometer slower than two readings per host stale bound (8 Hz) made every run end "lost: phone" (a
3 Hz gyroscope: 141 gaps): now refused naming the key.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli import main
from hil.scenario import parse_scenario
from hil.scenario.paths import FIXTURES
from hil.scenario.reader import MIN_NEEDED_SENSOR_RATE_HZ
from protocol.errors import ConfigError

BASE = "[scenario]\nname='x'\n"
AXES = "gimbal_axes=[[1,0,0],[0,1,0],[0,0,1]]\nspin_axes=[[0,1,0],[0,0,1],[1,0,0]]\n"


@pytest.mark.parametrize(
    ("array", "key", "geometry"),
    [
        ("geometry='tetrahedron'\nunits=6\n", "units", "tetrahedron"),
        ("geometry='tetrahedron'\nskew_deg=30\n", "skew_deg", "tetrahedron"),
        ("geometry='pyramid'\n" + AXES, "gimbal_axes", "pyramid"),
        ("units=4\nspin_axes=[[0,1,0],[0,0,1],[1,0,0],[0,0,1]]\n", "spin_axes", "pyramid"),
        ("geometry='custom'\nunits=3\n" + AXES, "units", "custom"),
        ("geometry='custom'\nskew_deg=40\n" + AXES, "skew_deg", "custom"),
    ],
)
def test_a_key_the_geometry_does_not_take_is_refused_naming_it(array, key, geometry):
    with pytest.raises(ConfigError) as caught:
        parse_scenario(f"{BASE}[array]\n{array}", Path("x.toml"))
    assert caught.value.where == f"x.toml: array.{key}"
    assert f"geometry {geometry!r}" in caught.value.detail and "which takes" in caught.value.detail


@pytest.mark.parametrize(
    ("array", "units"),
    [
        ("geometry='tetrahedron'\n", 3),
        ("geometry='pyramid'\nunits=6\nskew_deg=40\n", 6),
        ("geometry='custom'\n" + AXES, 3),
    ],
)
def test_each_geometrys_own_keys_are_taken(array, units):
    assert parse_scenario(f"{BASE}[array]\n{array}", Path("x.toml")).n_units == units


def test_firmware_sim_refuses_a_tetrahedron_of_six_units(tmp_path, capsys):
    from firmware_sim.cli import main as firmware_main

    text = (FIXTURES / "scenarios" / "cubesat-1u.toml").read_text()
    text = text.replace('geometry = "pyramid"', 'geometry = "tetrahedron"', 1)
    path = tmp_path / "tetra6.toml"
    path.write_text(text)
    assert firmware_main(["--world", str(path), "--duration", "0.3"]) == 2
    err = capsys.readouterr().err
    assert "tetra6.toml: array.units" in err and "Traceback" not in err, err


@pytest.mark.parametrize("kind", ["gyr", "acc"])
@pytest.mark.parametrize("rate", [1.0, 3.0, MIN_NEEDED_SENSOR_RATE_HZ - 0.5])
def test_a_needed_sensor_too_slow_to_steer_on_is_refused_naming_the_key(kind, rate):
    with pytest.raises(ConfigError) as caught:
        parse_scenario(f"{BASE}[sensors.{kind}]\nrate_hz={rate}\n", Path("x.toml"))
    assert caught.value.where == f"x.toml: sensors.{kind}.rate_hz"
    assert f"at least {MIN_NEEDED_SENSOR_RATE_HZ:g} Hz" in caught.value.detail


def test_the_floor_and_a_slow_magnetometer_are_taken():
    text = f"{BASE}[sensors.gyr]\nrate_hz={MIN_NEEDED_SENSOR_RATE_HZ}\n[sensors.mag]\nrate_hz=1.0\n"
    phone = parse_scenario(text, Path("x.toml")).phone
    assert phone.gyr.rate_hz == MIN_NEEDED_SENSOR_RATE_HZ and phone.mag.rate_hz == 1.0


def test_hil_run_refuses_a_three_hertz_gyroscope_before_it_runs(tmp_path, capsys):
    text = (FIXTURES / "scenarios" / "cubesat-1u.toml").read_text()
    text = text.replace("[sensors.mag]\n", "[sensors.gyr]\nrate_hz = 3.0\n[sensors.mag]\n", 1)
    path = tmp_path / "gyro3hz.toml"
    path.write_text(text)
    status = main(
        ["run", "--scenario", str(path), "--no-plots", "--duration", "5", "--out", str(tmp_path / "runs")]
    )
    err = capsys.readouterr().err
    assert status == 2 and "gyro3hz.toml: sensors.gyr.rate_hz" in err, err
    assert not (tmp_path / "runs").exists()

"""Dispersions that were never made: ``relative_sigma`` about a mean of 0, and sensor rates the host
cannot steer on.

``inertia_offdiag = { dist = "normal", relative_sigma = 0.5 }`` (the scenario's products of inertia are 0)
drew 0 in every run: σ = 0.5 × 0. Now refused, naming the file and key and suggesting ``sigma``. A
dispersion of the gyroscope's or accelerometer's rate below the scenario's floor (two readings per stale
bound) made runs that all ended "lost: phone": now refused, and a normal's tail clipped up to the floor.
"""

from __future__ import annotations

import pytest

from hil.cli import main
from hil.montecarlo.dispersions import draw, parse_dispersions
from hil.scenario import load_scenario
from hil.scenario.reader import MIN_NEEDED_SENSOR_RATE_HZ
from protocol.errors import ConfigError


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("cubesat-1u")


@pytest.mark.parametrize(
    "text, key",
    [
        ('[spacecraft]\ninertia_offdiag = { dist = "normal", relative_sigma = 0.5 }\n', "inertia_offdiag"),
        (
            '[spacecraft]\ninertia_scale = { dist = "normal", mean = 0, relative_sigma = 0.5 }\n',
            "inertia_scale",
        ),
        ('[initial]\nangle_deg = { dist = "normal", relative_sigma = 0.1 }\n', "angle_deg"),
    ],
)
def test_relative_sigma_about_a_zero_mean_is_refused_naming_the_key(scenario, text, key):
    with pytest.raises(ConfigError) as caught:
        parse_dispersions(text, scenario, "my.toml")
    assert caught.value.where.startswith("my.toml: ") and caught.value.where.endswith(f"{key}.relative_sigma")
    assert "sigma" in caught.value.detail and "no run would be dispersed" in caught.value.detail


def test_relative_sigma_about_a_nonzero_mean_disperses(scenario):
    d = parse_dispersions(
        '[spacecraft]\ninertia_scale = { dist = "normal", relative_sigma = 0.05 }\n', scenario
    )
    draws = {tuple(draw(d, 1, i).values["spacecraft.inertia_scale"]) for i in range(4)}
    assert len(draws) == 4


def test_the_cli_refuses_such_a_file_before_any_run(tmp_path, capsys):
    bad = tmp_path / "zero.toml"
    bad.write_text('[spacecraft]\ninertia_offdiag = { dist = "normal", relative_sigma = 0.5 }\n')
    status = main(
        ["montecarlo", "cubesat-1u", "--dispersions", str(bad), "--runs", "1", "--out", str(tmp_path / "mc")]
    )
    err = capsys.readouterr().err
    assert status == 2 and "zero.toml: spacecraft.inertia_offdiag.relative_sigma" in err, err
    assert not (tmp_path / "mc").exists()


@pytest.mark.parametrize("kind", ["gyr", "acc"])
@pytest.mark.parametrize(
    "dist",
    ["3.0", '{ dist = "uniform", low = 2.0, high = 50.0 }', '{ dist = "normal", mean = 5.0, sigma = 1.0 }'],
)
def test_a_needed_sensors_rate_below_the_floor_is_refused(scenario, kind, dist):
    with pytest.raises(ConfigError) as caught:
        parse_dispersions(f"[sensors.{kind}]\nrate_hz = {dist}\n", scenario, "my.toml")
    assert caught.value.where == f"my.toml: sensors.{kind}.rate_hz"


def test_a_normals_tail_is_clipped_up_to_the_floor_and_the_magnetometer_may_be_slow(scenario):
    d = parse_dispersions(
        '[sensors.gyr]\nrate_hz = { dist = "normal", mean = 10.0, sigma = 20.0 }\n'
        '[sensors.mag]\nrate_hz = { dist = "uniform", low = 2.0, high = 4.0 }\n',
        scenario,
    )
    gyr = [float(draw(d, 3, i).values["sensors.gyr.rate_hz"][0]) for i in range(200)]
    assert min(gyr) == MIN_NEEDED_SENSOR_RATE_HZ and max(gyr) > 10.0
    mag = [float(draw(d, 3, i).values["sensors.mag.rate_hz"][0]) for i in range(20)]
    assert min(mag) < MIN_NEEDED_SENSOR_RATE_HZ

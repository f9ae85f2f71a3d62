"""Fault times and sizes as firmware-sim and the dispersion files take them, alike.

``firmware-sim --phone-spoof 1e300:huge`` was accepted and never fired, while every other fault's time must
be within 0..86400 s; a dispersion's ``phone_jump`` with a fixed ``offset_s = 0`` became a 1 ms jump,
unsaid, where ``firmware-sim --phone-jump 12:0`` is refused.
"""

from __future__ import annotations

import pytest

from hil.montecarlo.dispersions import parse_dispersions
from hil.scenario import load_scenario
from hil.scenario.fault_specs import (
    parse_dead_esc,
    parse_jump,
    parse_noise,
    parse_sag,
    parse_spoof,
    parse_stall,
    parse_time,
)
from protocol.errors import ConfigError

PARSERS = {
    "--stall": lambda at: parse_stall(f"{at}:1"),
    "--phone-gap": lambda at: parse_stall(f"{at}:1", "--phone-gap"),
    "--hang-at": lambda at: parse_time(at, "--hang-at"),
    "--brownout-at": lambda at: parse_time(at, "--brownout-at"),
    "--noise": lambda at: parse_noise(f"{at}:1:0.1"),
    "--phone-jump": lambda at: parse_jump(f"{at}:5"),
    "--phone-spoof": lambda at: parse_spoof(f"{at}:huge"),
    "--sag": lambda at: parse_sag(f"3@{at}"),
    "--dead-esc": lambda at: parse_dead_esc(f"1@{at}"),
}


@pytest.mark.parametrize("option", sorted(PARSERS))
@pytest.mark.parametrize("at", ["1e300", "86400.001", "-1", "1e6"])
def test_every_fault_time_is_within_a_day(option, at):
    with pytest.raises(ConfigError) as caught:
        PARSERS[option](at)
    assert caught.value.where == option
    assert "0..86400 s" in caught.value.detail


@pytest.mark.parametrize("option", sorted(PARSERS))
@pytest.mark.parametrize("at", ["0", "12.5", "86400"])
def test_every_fault_time_within_a_day_is_taken(option, at):
    PARSERS[option](at)


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("cubesat-1u")


@pytest.mark.parametrize(
    "offset",
    ["0", "0.0", "-0.0", '{ dist = "choice", values = [0, 5] }', '{ dist = "normal", mean = 0, sigma = 0 }'],
)
def test_a_dispersion_s_phone_jump_of_0_s_is_refused_as_firmware_sim_refuses_it(scenario, offset):
    text = f"[faults]\nphone_jump = {{ count = 1, offset_s = {offset} }}\n"
    with pytest.raises(ConfigError, match="must be non-zero") as caught:
        parse_dispersions(text, scenario, "d.toml")
    assert caught.value.where == "d.toml: faults.phone_jump.offset_s"
    with pytest.raises(ConfigError, match="non-zero"):
        parse_jump("12:0")


@pytest.mark.parametrize("offset", ["-5", "0.5", '{ dist = "uniform", low = -1, high = 1 }'])
def test_a_dispersion_s_non_zero_phone_jump_is_taken(scenario, offset):
    parse_dispersions(f"[faults]\nphone_jump = {{ count = 1, offset_s = {offset} }}\n", scenario, "d.toml")

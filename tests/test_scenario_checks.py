"""Bad scenario, dispersion and run-directory input: one error naming the file and key, bounded cost.
Also the small things a newcomer meets in ``hil run --help`` and the package metadata."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.board.config import BoardConfig
from hil.cli import main
from hil.montecarlo.dispersions import draw, load_dispersions, parse_dispersions
from hil.scenario import load_scenario, parse_scenario
from hil.scenario.paths import ROOT
from hil.scenario.reader import BOARD_RANGES
from protocol.errors import ConfigError

BASE = "[scenario]\nname='x'\n"


@pytest.mark.parametrize(
    ("text", "where", "detail"),
    [
        ("[array]\ngeometry='pyramid'\nskew_deg=90\n", "x.toml: array.skew_deg", "degenerate"),
        ("[array]\ngeometry='pyramid'\nskew_deg=2\n", "x.toml: array.skew_deg", "degenerate"),
        ("[manoeuvre]\nangle_deg=1e308\n", "x.toml: manoeuvre.angle_deg", "360"),
        ("[manoeuvre]\ninitial_angle_deg=-1e308\n", "x.toml: manoeuvre.initial_angle_deg", "360"),
        ("[scenario]\nname='x'\nduration_s=1e308\n", "x.toml: scenario.duration_s", "at most"),
        ("[board]\nlink_timeout=-1\n", "x.toml: board.link_timeout", "0.01..60"),
        ("[board]\ncells=13\n", "x.toml: board.cells", "2..12"),
        ("[board]\ncells=1\n", "x.toml: board.cells", "2..12"),  # the rail cannot boot the MCU
        ("[scenario]\nname='x'\ndescription=[1, {a = 2}]\n", "x.toml: scenario.description", "a string"),
        ("[board]\ncells=3.5\n", "x.toml: board.cells", "integer"),
        ("[board]\nsoc=1.5\n", "x.toml: board.soc", "0..1"),
        # parse, and lie within the ranges, but no spacecraft or phone is made of them
        ("[spacecraft]\nbus_inertia=[5e-324, 5e-324, 5e-324]\n", "x.toml: spacecraft", "smallest principal"),
        (
            "[array]\ngeometry='custom'\ngimbal_axes=[[0,0,1]]\nspin_axes=[[1,0,0]]\n",
            "x.toml: array.gimbal_axes",
            "all parallel",
        ),
        (
            "[array]\ngeometry='custom'\ngimbal_axes=[[0,0,1],[0,0.01,1],[0,0,-1]]\n"
            "spin_axes=[[1,0,0],[0,1,-0.01],[1,0,0]]\n",
            "x.toml: array.gimbal_axes",
            "all parallel",
        ),
        # [faults]: checked as the file is read, not a run and a warm-up later by the board (issue 27)
        ("[faults]\nhang_at='nan'\n", "x.toml: faults.hang_at", "not a time"),
        ("[faults]\nbrownout_at=1e12\n", "x.toml: faults.brownout_at", "0..86400"),
        ("[faults]\nstall=['-5:-1']\n", "x.toml: faults.stall", "not a time"),
        ("[faults]\nstall=['5:0']\n", "x.toml: faults.stall", "duration > 0"),
        ("[faults]\nstall='5'\n", "x.toml: faults.stall", "AT:DURATION"),
        ("[faults]\nsag=1e160\n", "x.toml: faults.sag", "0..100"),
        ("[faults]\nsag='6@1e12'\n", "x.toml: faults.sag", "not a time"),
        ("[faults]\nsag_ohms='-1@3'\n", "x.toml: faults.sag_ohms", "0..100"),
        ("[faults]\ndead_esc=['8@3']\n", "x.toml: faults.dead_esc", "channel 8 does not exist"),
        ("[faults]\ndead_esc=['1@-3']\n", "x.toml: faults.dead_esc", "not a time"),
        ("[faults]\ncorrupt=1.5\n", "x.toml: faults.corrupt", "probability"),
        ("[faults]\nfault_direction='up'\n", "x.toml: faults.fault_direction", "rx, tx, both"),
        # strings and booleans in a list of numbers: numpy read "2e-3" as 0.002 and true as 1.0 (a single
        # value refused them; a list took them)
        ("[sensors]\nfield_enu_uT=[true, true, true]\n", "x.toml: sensors.field_enu_uT", "must be numbers"),
        ("[spacecraft]\nbus_inertia=[1e-3, '2e-3', 2e-3]\n", "x.toml: spacecraft.bus_inertia", "3 diagonal"),
        ("[manoeuvre]\naxis=['1', '2', '2']\n", "x.toml: manoeuvre.axis", "must be numbers"),
        (
            "[array]\ngeometry='custom'\ngimbal_axes=[['0',0,1],[1,0,0],[0,1,0]]\n"
            "spin_axes=[[1,0,0],[0,1,0],[0,0,1]]\n",
            "x.toml: array.gimbal_axes",
            "finite numbers",
        ),
        (
            "[sensors]\nfield_enu_uT=[0.0, 0.0, -40.0]\n",
            "x.toml: sensors.field_enu_uT",
            "parallel to gravity",
        ),
        ("[faults]\ncorrupt=[0.1, 0.2]\n", "x.toml: faults.corrupt", "one value"),
        ("[faults]\ndrop=[0.1, 0.2]\n", "x.toml: faults.drop", "one value"),
        ("[faults]\nfault_direction=['rx', 'tx']\n", "x.toml: faults.fault_direction", "one value"),
        # the host's setpoints feed the board's link watchdog: a control period that is not within the
        # link timeout is a run whose board fails safe between commands (it ran, and was lost, before)
        ("[controller]\ncontrol_rate_hz=4\n", "x.toml: controller.control_rate_hz", "link timeout of 0.25"),
        ("[controller]\ncontrol_rate_hz=1\n", "x.toml: controller.control_rate_hz", "every 1 s"),
        (
            "[controller]\ncontrol_rate_hz=10\n[board]\nlink_timeout=0.05\n",
            "x.toml: controller.control_rate_hz",
            "board.link_timeout",
        ),
    ],
)
def test_values_the_parts_cannot_take_are_refused_naming_file_and_key(text, where, detail):
    doc = text if text.startswith("[scenario]") else BASE + text
    with pytest.raises(ConfigError, match=detail) as info:
        parse_scenario(doc, Path("x.toml"))
    assert info.value.where == where


_FIELDS = {"frame_rate": "frame_rate_hz", "telemetry_rate": "telemetry_rate_hz",
           "heartbeat_rate": "heartbeat_rate_hz", "link_timeout": "link_timeout_s",
           "mcu_watchdog": "mcu_watchdog_s"}  # fmt: skip


@pytest.mark.parametrize("key", sorted(BOARD_RANGES))
def test_the_scenario_board_ranges_are_the_boards_own(key):
    """What the scenario reader accepts is exactly what BoardConfig accepts, at both ends."""
    lo, hi, kind = BOARD_RANGES[key]
    step = 1 if kind is int else 1e-6 * max(1.0, abs(hi))

    def board_takes(value: float) -> bool:
        base = BoardConfig()
        try:
            if key in _FIELDS:
                base.replace(**{_FIELDS[key]: value})
            else:
                battery = dataclasses.replace(
                    base.power.battery, **{"cells" if key == "cells" else "initial_soc": value}
                )
                base.replace(power=dataclasses.replace(base.power, battery=battery))
        except ConfigError:
            return False
        return True

    # a control period within the shortest link timeout the board takes (0.01 s), at a frame rate that
    # keeps up with it (both checked by the reader)
    rate, frames = (200, "frame_rate=200\n") if key == "link_timeout" else (10, "")

    def scenario_takes(value: float) -> bool:
        try:
            text = f"[controller]\ncontrol_rate_hz={rate}\n[board]\n{frames}{key}={value!r}\n"
            parse_scenario(BASE + text, Path("x.toml"))
        except ConfigError as exc:
            assert exc.where == f"x.toml: board.{key}"
            return False
        return True

    from hil.scenario.reader import MIN_RUN_SOC, MIN_TELEMETRY_RATE_HZ

    for value in (lo, hi, kind(lo - step), kind(hi + step)):
        if key == "telemetry_rate" and value < MIN_TELEMETRY_RATE_HZ:  # the host's stale bound: stricter
            assert not scenario_takes(value), value
            continue
        if key == "soc" and value < MIN_RUN_SOC:  # a pack too flat to fly a run: stricter
            assert not scenario_takes(value), value
            continue
        assert scenario_takes(value) == board_takes(value), value


def test_binary_scenario_and_dispersion_files_are_one_line_naming_the_file(tmp_path, capsys):
    binary = tmp_path / "scenario.toml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe" * 50)
    with pytest.raises(ConfigError, match="not a text file") as info:
        load_scenario(binary)
    assert str(binary) in str(info.value)
    assert main(["run", "--scenario", str(binary)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(binary) in err[0]
    with pytest.raises(ConfigError, match="not a text file"):
        load_dispersions(binary, load_scenario("cubesat-1u"))


def test_a_binary_run_directory_file_is_one_line_naming_it(tmp_path, capsys):
    (tmp_path / "telemetry.csv").write_bytes(b"\xff\xfe\x00t,phase\n" + bytes(range(256)))
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "telemetry.csv" in err[0] and "not a text file" in err[0]


@pytest.mark.parametrize(
    ("value", "detail"),
    [
        ("1e12", "outside 0..600"),
        ("-3", "outside 0..600"),
        ("{ dist = 'normal', mean = 1e12, sigma = 1 }", "outside"),
    ],
)
def test_link_outage_rates_are_bounded(value, detail):
    sc = load_scenario("cubesat-1u")
    text = f"[link]\noutages_per_minute = {value}\noutage_duration_s = 0.5\n"
    with pytest.raises(ConfigError, match=detail) as info:
        parse_dispersions(text, sc, "d.toml")
    assert info.value.where == "d.toml: link.outages_per_minute"


def test_a_normal_rate_tail_is_clipped_so_a_run_s_outages_stay_bounded():
    sc = load_scenario("cubesat-1u")
    rate = "{ dist = 'normal', mean = 600, sigma = 500 }"  # its tail past the range: clipped
    d = parse_dispersions(f"[link]\noutages_per_minute = {rate}\noutage_duration_s = 0.1\n", sc, "d.toml")
    for i in range(5):
        assert len(draw(d, 1, i).outages) < 2 * 600 * sc.slew.duration_s / 60


def test_hil_run_refuses_a_duration_of_nan_and_its_help_tells_defaults_and_udp(capsys):
    for bad in ("nan", "inf", "-1", "0"):
        with pytest.raises(SystemExit) as info:
            main(["run", "--duration", bad])
        assert info.value.code == 2 and "--duration" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    out = capsys.readouterr().out
    assert "phone over UDP" in out and "over HTTP" not in out
    assert "scenario's duration_s" in out and "default 10 s" in out


def test_package_metadata_uses_an_spdx_license_string():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"  # a string: setuptools deprecates license = { text = ... }


def test_a_scenario_s_faults_reach_the_board_as_written_negative_looking_values_included():
    """Each [faults] value goes to firmware-sim as ``--option=value``: a stall's ``AT:DURATION`` is the
    option's, even where it would look like another option to argparse; and the board schedules it."""
    from firmware_sim.cli import build_parser, make_board
    from hil.timing.clock import LockstepClock

    doc = BASE + "[faults]\nstall=['5:2', '7.5:0.25']\nhang_at=[3.0]\nsag='6@10/5'\ndead_esc=['1@3']\n"
    scenario = parse_scenario(doc, Path("x.toml"))
    argv = scenario.firmware_sim_argv()
    assert "--stall=5:2" in argv and "--sag=6@10/5" in argv
    board = make_board(build_parser().parse_args(argv), LockstepClock())
    assert len(board.faults.stalls) == 2 and board.faults.hangs and board.faults.dead_escs


def test_a_dispersed_sensor_rate_below_1_hz_is_a_run_the_model_refuses():
    """A dispersion's draw of a phone sensor's rate (5e-324 Hz) is held to what a scenario may say (1 Hz
    or more): the run fails naming the parameter (its magnetometer never sampled, and it said ok)."""
    from hil.scenario.phone import SensorSpec

    with pytest.raises(ConfigError, match="1 Hz or more"):
        SensorSpec(rate_hz=5e-324, noise=0.0, bias=0.0)
    assert SensorSpec(rate_hz=1.0, noise=0.0, bias=0.0, jitter_s=0.0).rate_hz == 1.0


def test_the_scenario_link_timeout_default_is_the_boards():
    from hil.scenario.reader import DEFAULT_LINK_TIMEOUT_S

    assert DEFAULT_LINK_TIMEOUT_S == BoardConfig().link_timeout_s


def test_a_slow_control_rate_within_a_longer_link_timeout_is_a_scenario():
    doc = BASE + "[controller]\ncontrol_rate_hz=2\n[board]\nlink_timeout=1.0\n"
    assert parse_scenario(doc, Path("x.toml")).loop.control_rate_hz == 2.0


@pytest.mark.parametrize("key", ["noise", "bias", "jitter_s", "offset_s"])
def test_a_negative_zero_sensor_figure_is_zero_and_the_phone_samples(key):
    """``-0.0`` lies within ``0..`` but numpy's samplers refuse it as a scale ("scale < 0", a traceback
    from the run before): every sensor's figure is held as +0.0, and the world's phone samples with it."""
    from firmware_sim.world.models.phone import BodyPhone

    doc = BASE + "".join(f"[sensors.{kind}]\n{key} = -0.0\n" for kind in ("gyr", "acc", "mag"))
    phone = parse_scenario(doc, Path("x.toml")).phone
    for kind in (phone.gyr, phone.acc, phone.mag):
        value = getattr(kind, key)
        assert value == 0.0 and str(value) == "0.0"
    times = np.arange(0.0, 0.2, 0.001)
    path = np.array([np.concatenate([[t], np.eye(3).ravel(), np.zeros(3)]) for t in times])
    samples = BodyPhone(phone, seed=3).sample_path(path)
    assert samples and all(np.all(np.isfinite(s.xyz)) for s in samples)

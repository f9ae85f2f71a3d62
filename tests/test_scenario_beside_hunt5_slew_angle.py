"""A scenario's ``manoeuvre.angle_deg`` beyond ±180 deg. The slew is rest-to-rest between two attitudes and
the host flies it the short way, so ``angle_deg = 270.0`` about ``[1, 2, 2]`` was flown, without a word, as
90 deg about ``[-1, -2, -2]`` (the run's ``slew_start`` event said 91.5 deg and the run "completed"), and
``360.0`` as no slew at all. Refused as the file is read, naming the file, the key and why; every angle
taken is the turn the run plans."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil import so3
from hil.scenario import load_scenario
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]


def _write(folder: Path, angle: float, axis: tuple[float, float, float] = (1.0, 2.0, 2.0)) -> Path:
    path = folder / "my.toml"
    path.write_text(
        "[scenario]\nname = 'my'\nduration_s = 3\n"
        f"[manoeuvre]\naxis = [{axis[0]!r}, {axis[1]!r}, {axis[2]!r}]\nangle_deg = {angle!r}\n"
    )
    return path


beyond_half_turn = st.floats(min_value=180.0, max_value=360.0, exclude_min=True)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(angle=beyond_half_turn, sign=st.sampled_from([1.0, -1.0]))
def test_a_slew_beyond_half_a_turn_is_refused_naming_file_and_key(tmp_path, angle, sign):
    with pytest.raises(ConfigError) as caught:
        load_scenario(_write(tmp_path, sign * angle))
    assert caught.value.where == "my.toml: manoeuvre.angle_deg"
    assert "must be within -180..180 deg" in caught.value.detail
    assert "the short way" in caught.value.detail


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    angle=st.floats(min_value=-180.0, max_value=180.0).filter(lambda a: abs(a) > 1e-6),
    axis=st.tuples(*[st.floats(min_value=-10.0, max_value=10.0)] * 3).filter(
        lambda v: float(np.linalg.norm(v)) > 1e-3
    ),
)
def test_every_slew_taken_is_the_turn_the_run_plans(tmp_path, angle, axis):
    """The planned slew (start to target attitude) turns by the angle written, about the axis written
    (its sign and the angle's together), within rounding."""
    slew = load_scenario(_write(tmp_path, angle, axis)).slew
    turn = np.asarray(slew.R0).T @ np.asarray(slew.R_target)
    assert math.degrees(so3.principal_angle(turn)) == pytest.approx(abs(angle), abs=1e-6)
    if abs(angle) < 179.0:  # at half a turn the two directions are one attitude
        flown = so3.log(turn)
        written = math.radians(angle) * np.asarray(axis) / np.linalg.norm(axis)
        np.testing.assert_allclose(flown, written, atol=1e-6)


@pytest.mark.parametrize("angle", [270.0, 360.0, -200.0])
def test_hil_run_refuses_the_slew_before_it_starts(tmp_path, angle):
    path = _write(tmp_path, angle)
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--out", str(tmp_path / "runs"), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert "my.toml: manoeuvre.angle_deg: must be within -180..180 deg" in lines[0]
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_firmware_sim_refuses_the_world_at_start(tmp_path, capsys):
    from firmware_sim.cli import main

    assert main(["--world", str(_write(tmp_path, 270.0)), "--duration", "0.01"]) == 2
    assert "my.toml: manoeuvre.angle_deg: must be within -180..180 deg" in capsys.readouterr().err

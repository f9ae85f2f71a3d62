"""A bus too small for its rotors' momentum. The gimbals' rate servos turn each gimbal against the bus, and
the bus, turned by the gimbals' motion, carries them with it (``γ̈ = −γ̇/τ_g + h̄ Gᵀ J⁻¹ T γ̇``): once that
coupling λ nears the servos' 1/τ_g the gimbals no longer follow their commands. A 1U CubeSat with
``bus_inertia = [3e-4, 3e-4, 3e-4]`` (h̄/J 13 rad/s, λ τ_g 0.93) was read as a scenario, and ``hil run``
of it tumbled — its gimbals racing at 1.6 rad/s against commands of 0.04 — and ended ``exit completed``,
status 0, 179 deg off its target. Refused as the file is read, naming the key and the bus that would do
(:data:`hil.scenario.reader.GIMBAL_COUPLING_MARGIN`)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import SCENARIO_DIR, load_scenario
from protocol.errors import ConfigError

BASE = (SCENARIO_DIR / "cubesat-1u.toml").read_text()


def _write(folder: Path, inertia: str, speed: float = 400.0) -> Path:
    path = folder / "small-bus.toml"
    text = BASE.replace(
        "nominal_rotor_speed = 400.0", f"nominal_rotor_speed = {speed!r}\nbus_inertia = {inertia}"
    )
    assert text != BASE
    path.write_text(text)
    return path


def _hil_run(scenario: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "run", "--scenario", str(scenario), "--out", str(out), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=240,
    )


def test_hil_run_refuses_a_bus_whose_gimbals_it_would_carry_away(tmp_path):
    result = _hil_run(_write(tmp_path, "[3e-4, 3e-4, 3e-4]"), tmp_path / "runs")
    assert result.returncode != 0, result.stdout[-600:]  # it "completed", status 0, 179 deg off
    assert "small-bus.toml: spacecraft.bus_inertia" in result.stderr
    assert "λ τ_g = 0.93" in result.stderr and "Traceback" not in result.stderr
    assert not list((tmp_path / "runs").glob("*/summary.json"))


def test_a_bus_just_within_the_bound_flies_its_slew(tmp_path):
    """The near side: λ τ_g 0.62 (a bus of 5e-4 kg m², four times smaller than the shipped one) runs and
    settles within the requirement: the bound refuses what cannot fly, not what can."""
    result = _hil_run(_write(tmp_path, "[5e-4, 5e-4, 5e-4]"), tmp_path / "runs")
    assert result.returncode == 0, result.stderr[-800:]
    (summary_path,) = (tmp_path / "runs").glob("*/summary.json")
    summary = json.loads(summary_path.read_text())
    assert summary["exit"] == "completed" and summary["requirement"]["met"] is True


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    inertia=st.floats(5e-5, 5e-3),
    speed=st.sampled_from([150.0, 250.0, 400.0, 600.0]),
)
def test_the_bus_the_error_asks_for_is_taken_and_a_larger_one_too(tmp_path, inertia, speed):
    """Whatever bus and rotor speed: a refused bus names the key and a least bus, which is taken (so is
    one larger still); a bus taken stays taken when made larger (the bound is one-sided)."""
    try:
        load_scenario(_write(tmp_path, f"[{inertia!r}, {inertia!r}, {inertia!r}]", speed))
    except ConfigError as exc:
        assert exc.where == "small-bus.toml: spacecraft.bus_inertia"
        least = float(re.search(r"a diagonal of \[([0-9.e+-]+),", exc.detail).group(1))
        assert least > inertia
        for taken in (least, 1.5 * least):
            load_scenario(_write(tmp_path, f"[{taken!r}, {taken!r}, {taken!r}]", speed))
    else:
        bigger = 1.5 * inertia
        load_scenario(_write(tmp_path, f"[{bigger!r}, {bigger!r}, {bigger!r}]", speed))


@pytest.mark.parametrize("name", ["cubesat-1u", "paper-testbed"])
def test_the_shipped_scenarios_are_within_the_bound(name):
    load_scenario(name)

"""The rotors spin up with the gimbals still, so whatever momentum they then carry goes into the bus. A
pyramid at gimbal angles of 90 deg x 4, or a custom array on x, y and z (spinning along y, z and x at zero),
carries a net momentum at spin-up: the spacecraft rolled at 3-6 rad/s before its "rest-to-rest" slew, and
``hil run`` "completed" 64-153 deg off its target. Now a scenario whose start angles spin the bus faster
than the slew's own ``max_rate`` is refused naming ``manoeuvre.gimbal_angles_deg`` (with the momentum and
the rate); a custom array given no angles starts at gimbal angles where its rotors' momenta cancel, or is
refused naming ``array.spin_axes`` when none is found."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import load_scenario, parse_scenario
from hil.vscmg.geometry import spin_axes_at
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]
XYZ_GIMBALS = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
XYZ_SPINS = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]


def _spin_up_rate(scenario) -> float:
    """The body rate (rad/s) the spin-up leaves, from the rotors' spin momenta (n h̄ along each spin axis at
    the start angles) over the spacecraft's inertia with its units (computed here from the parts, not the
    reader's helper)."""
    sc = scenario.world_spacecraft
    h = np.array([u.rotor_spin_inertia for u in sc.units]) * sc.nominal_rotor_speed
    momentum = h @ spin_axes_at(sc.units, np.asarray(scenario.slew.gimbal_angle0, dtype=float))
    from hil.vscmg.plant_model import PlantModel

    plant = PlantModel(sc)
    inertia = plant.locked_inertia(plant.state(gimbal_angle=scenario.slew.gimbal_angle0))[0]
    return float(np.linalg.norm(np.linalg.solve(inertia, momentum)))


def _pyramid(angles: list[float], max_rate: float = 0.15) -> str:
    return (
        "[scenario]\nname = 'spin'\nduration_s = 5\n"
        f"[manoeuvre]\nmax_rate = {max_rate!r}\ngimbal_angles_deg = {angles!r}\n"
    )


@settings(max_examples=60, deadline=None)
@given(
    angles=st.lists(st.floats(-360.0, 360.0, allow_nan=False), min_size=4, max_size=4),
    max_rate=st.sampled_from([0.05, 0.15, 1.0]),
)
def test_start_angles_that_spin_the_bus_faster_than_the_slew_are_refused_naming_the_key(angles, max_rate):
    try:
        scenario = parse_scenario(_pyramid(angles, max_rate), Path("spin.toml"))
    except ConfigError as exc:
        assert exc.where == "spin.toml: manoeuvre.gimbal_angles_deg"
        assert "N m s" in exc.detail and "rad/s" in exc.detail and "max_rate" in exc.detail
        return
    assert _spin_up_rate(scenario) <= max_rate * (1 + 1e-9)


def test_the_pyramid_at_ninety_degrees_is_refused_with_its_momentum_and_rate():
    with pytest.raises(ConfigError) as caught:
        parse_scenario(_pyramid([90.0, 90.0, 90.0, 90.0]), Path("spin.toml"))
    assert caught.value.where == "spin.toml: manoeuvre.gimbal_angles_deg"
    assert "0.0131 N m s" in caught.value.detail and "5.64 rad/s" in caught.value.detail


def test_momentum_cancelling_start_angles_are_taken():
    # opposite units at +90 and -90 deg: their momenta cancel, as at zero
    scenario = parse_scenario(_pyramid([90.0, -90.0, 90.0, -90.0]), Path("spin.toml"))
    assert _spin_up_rate(scenario) < 1e-9
    assert np.degrees(scenario.slew.gimbal_angle0).tolist() == [90.0, -90.0, 90.0, -90.0]


def _custom(folder: Path, gimbals, spins, duration: float = 5.0) -> Path:
    path = folder / "xyz.toml"
    path.write_text(
        f"[scenario]\nname = 'xyz'\nduration_s = {duration!r}\n"
        f"[array]\ngeometry = 'custom'\ngimbal_axes = {gimbals!r}\nspin_axes = {spins!r}\n"
    )
    return path


unit_axis = st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 0.2)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(axes=st.lists(unit_axis, min_size=3, max_size=6))
def test_a_custom_array_starts_where_its_momenta_cancel_or_is_refused(tmp_path, axes):
    gimbals = [[float(x) for x in np.asarray(a) / np.linalg.norm(a)] for a in axes]
    spins = []
    for g in gimbals:  # any axis across the gimbal axis
        other = np.array([1.0, 0.0, 0.0]) if abs(g[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        s = np.cross(g, other)
        spins.append([float(x) for x in s / np.linalg.norm(s)])
    try:
        scenario = load_scenario(_custom(tmp_path, gimbals, spins))
    except ConfigError as exc:
        assert exc.where in ("xyz.toml: array.spin_axes", "xyz.toml: array.gimbal_axes")
        return
    assert _spin_up_rate(scenario) <= 1e-6


def test_the_xyz_array_starts_at_its_zero_momentum_angles(tmp_path):
    scenario = load_scenario(_custom(tmp_path, XYZ_GIMBALS, XYZ_SPINS))
    assert np.allclose(np.degrees(scenario.slew.gimbal_angle0), -45.0, atol=1e-4)
    assert _spin_up_rate(scenario) < 1e-6


def test_hil_run_refuses_the_ninety_degree_pyramid_in_one_line(tmp_path):
    path = tmp_path / "spin.toml"
    path.write_text(_pyramid([90.0, 90.0, 90.0, 90.0]))
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "spin.toml: manoeuvre.gimbal_angles_deg:" in lines[0], lines
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_hil_run_of_the_xyz_array_does_not_tumble(tmp_path):
    """Through the CLI and the emulated board: the spacecraft stays well below a tumble through the
    spin-up and ends near its target (from zero gimbal angles it rolled at ~3 rad/s and ended 64-153 deg
    off)."""
    path = _custom(tmp_path, XYZ_GIMBALS, XYZ_SPINS, duration=25.0)
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (run_dir,) = (tmp_path / "runs").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["final_error_deg"] < 10.0, summary["final_error_deg"]
    import csv

    with open(run_dir / "telemetry.csv", newline="") as f:
        rates = [
            np.linalg.norm([float(row[f"true_w{a}"]) for a in "xyz"])
            for row in csv.DictReader(f)
            if row["true_wx"]
        ]
    assert max(rates) < 0.5, max(rates)

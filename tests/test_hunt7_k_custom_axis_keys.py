"""A custom ``[array]`` whose axes the units refuse — a gimbal or spin axis not of unit length (``[1, 1, 0]``
for 45 deg), a spin axis not across its gimbal axis — was an error at ``FILE: array.custom: unit 2:
UnitParams.gimbal_axis``: a key no scenario file has, and the parts' class name. Now it names the key
written, ``array.gimbal_axes`` or ``array.spin_axes``, and the unit."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import load_scenario
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]
GIMBALS = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
SPINS = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]


def _write(folder: Path, gimbals: list[list[float]], spins: list[list[float]]) -> Path:
    path = folder / "geo.toml"
    path.write_text(
        "[scenario]\nname = 'geo'\nduration_s = 3\n"
        f"[array]\ngeometry = 'custom'\ngimbal_axes = {gimbals!r}\nspin_axes = {spins!r}\n"
    )
    return path


scale = st.floats(min_value=0.5, max_value=10.0).filter(lambda k: abs(k - 1.0) > 1e-3)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(unit=st.integers(0, 2), k=scale, which=st.sampled_from(["gimbal_axes", "spin_axes"]))
def test_an_axis_not_of_unit_length_is_named_by_its_key_and_unit(tmp_path, unit, k, which):
    gimbals = [list(v) for v in GIMBALS]
    spins = [list(v) for v in SPINS]
    axes = gimbals if which == "gimbal_axes" else spins
    axes[unit] = [k * x for x in axes[unit]]
    with pytest.raises(ConfigError) as caught:
        load_scenario(_write(tmp_path, gimbals, spins))
    assert caught.value.where == f"geo.toml: array.{which}"
    assert caught.value.detail.startswith(f"unit {unit}: must have unit length")
    assert "UnitParams" not in str(caught.value)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(unit=st.integers(0, 2), tilt=st.floats(min_value=0.01, max_value=0.99))
def test_a_spin_axis_not_across_its_gimbal_is_named_by_its_key_and_unit(tmp_path, unit, tilt):
    spins = [list(v) for v in SPINS]
    along = GIMBALS[unit]
    across = SPINS[unit]
    c = (1.0 - tilt * tilt) ** 0.5  # a unit vector tilted towards the gimbal axis
    spins[unit] = [c * a + tilt * g for a, g in zip(across, along, strict=True)]
    with pytest.raises(ConfigError) as caught:
        load_scenario(_write(tmp_path, GIMBALS, spins))
    assert caught.value.where == "geo.toml: array.spin_axes"
    assert caught.value.detail.startswith(f"unit {unit}: must be perpendicular")


def test_the_unit_axes_are_taken(tmp_path):
    assert load_scenario(_write(tmp_path, GIMBALS, SPINS)).n_units == 3


def test_hil_run_names_the_key_with_exit_2(tmp_path):
    path = _write(tmp_path, [[1.0, 1.0, 0.0], *GIMBALS[1:]], SPINS[:1] + SPINS[1:])
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert "geo.toml: array.gimbal_axes: unit 0: must have unit length" in done.stderr
    assert "Traceback" not in done.stderr

"""A custom array with a gimbal axis of zero length (``[0, 0, 0]``, ``[-0.0, 0, 0]``, or one so small its
length underflows, ``[1e-300, 0, 0]``). The reader's three-axis check divided by the axes' lengths before
the axes were checked to be unit vectors, so ``hil run --scenario my.toml`` printed numpy's
``RuntimeWarning: invalid value encountered in divide`` with the reader's source line ahead of its error.
Now a zero axis is an error before the division: one line, naming the file, the key and the unit."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import load_scenario
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]
GIMBALS = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
SPINS = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]


def _write(folder: Path, gimbals: list[list[float]]) -> Path:
    path = folder / "my.toml"
    path.write_text(
        "[scenario]\nname = 'my'\nduration_s = 3\n"
        f"[array]\ngeometry = 'custom'\ngimbal_axes = {gimbals!r}\nspin_axes = {SPINS!r}\n"
    )
    return path


tiny = st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 5e-324, 1e-170])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(unit=st.integers(0, 2), axis=st.tuples(tiny, tiny, tiny))
def test_a_zero_gimbal_axis_is_an_error_naming_its_unit_and_no_warning(tmp_path, unit, axis):
    gimbals = [list(g) for g in GIMBALS]
    gimbals[unit] = list(axis)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning printed on the user's terminal fails here
        with pytest.raises(ConfigError) as caught:
            load_scenario(_write(tmp_path, gimbals))
    assert caught.value.where == "my.toml: array.gimbal_axes"
    assert f"unit {unit}: a zero vector" in caught.value.detail


def test_the_orthogonal_custom_array_is_taken(tmp_path):
    assert load_scenario(_write(tmp_path, GIMBALS)).n_units == 3


def test_hil_run_says_one_line(tmp_path):
    path = _write(tmp_path, [[0.0, 0.0, 0.0], *GIMBALS[1:]])
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--out", str(tmp_path / "runs"), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert "my.toml: array.gimbal_axes: unit 0: a zero vector" in lines[0]

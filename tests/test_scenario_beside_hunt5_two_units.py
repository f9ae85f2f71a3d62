"""A custom array of two units on axes apart. A pyramid of two is refused (``geometry.pyramid``: at least
3), but a custom array of two passed the reader's three-axis check: its CMG Jacobian D1 is 3 × 2, so the
singularity measure δ = det(D1 D1ᵀ) is 0 at every gimbal angle, and ``hil run`` of one (gimbals on x and y,
40 s) steered on the rotors alone and "completed" 20 deg off with a minimum δ of 0. Refused as the file is
read, naming the file and the key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hil.scenario import load_scenario
from protocol.errors import ConfigError

direction = st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _perpendicular(g: np.ndarray) -> np.ndarray:
    helper = np.array([1.0, 0.0, 0.0]) if abs(g[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    return _unit(np.cross(g, helper))


def _write(folder: Path, gimbals: list[np.ndarray]) -> Path:
    spins = [_perpendicular(g) for g in gimbals]
    path = folder / "my.toml"
    path.write_text(
        "[scenario]\nname = 'my'\nduration_s = 3\n[array]\ngeometry = 'custom'\n"
        f"gimbal_axes = {[[float(x) for x in g] for g in gimbals]!r}\n"
        f"spin_axes = {[[float(x) for x in s] for s in spins]!r}\n"
    )
    return path


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(a=direction, b=direction)
def test_a_custom_array_of_two_units_is_refused_naming_the_key(tmp_path, a, b):
    g1, g2 = _unit(a), _unit(b)
    assume(np.linalg.norm(np.cross(g1, g2)) > np.sin(np.radians(6.0)))  # apart: the three-axis check passes
    with pytest.raises(ConfigError) as caught:
        load_scenario(_write(tmp_path, [g1, g2]))
    assert caught.value.where == "my.toml: array.gimbal_axes"
    assert "at least 3 units" in caught.value.detail


def test_a_third_unit_on_either_axis_is_taken(tmp_path):
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    assert load_scenario(_write(tmp_path, [x, y, x])).n_units == 3
    assert load_scenario(_write(tmp_path, [x, y, np.array([0.0, 0.0, 1.0])])).n_units == 3

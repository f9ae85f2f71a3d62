"""The main field models at a geographic pole: the field there is the field a step away from it.

The east component of a spherical-harmonic field divides each ``P_n^m(sin φ)`` by ``cos φ``, which is 0 at a
pole; the synthesis clamped the cosine to 1e-12 and so lost the east component at ``--lat 90`` and
``--lat -90`` (both within :data:`hil.cli.replay.ANGLE_BOUNDS`): IGRF-14 at the south pole, lon 0, 2020
said declination 0.00° and inclination −74.50° where a millimetre away the field has −30.70° and −72.12°,
and ``hil replay --lat -90`` turned its estimates by that wrong declination without a word.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.geomag import GeomagneticField, igrf14, wmm2025

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"
NEAR_DEG = 1e-6  # ~0.1 m from the pole: the field differs from the pole's by far less than the tolerances


def _angle_apart(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _same_field(at_pole: GeomagneticField, near: GeomagneticField) -> None:
    assert _angle_apart(at_pole.declination_deg, near.declination_deg) < 1e-3, (at_pole, near)
    assert at_pole.inclination_deg == pytest.approx(near.inclination_deg, abs=1e-3)
    assert at_pole.total_nT == pytest.approx(near.total_nT, abs=0.5)


MODELS = {"igrf14": (igrf14, 1900.0, 2030.0), "wmm2025": (wmm2025, 2025.0, 2029.99)}
"""Each main field model with the years it covers."""


@pytest.mark.parametrize("model", sorted(MODELS))
@settings(max_examples=45, deadline=None)
@given(
    pole=st.sampled_from([90.0, -90.0]),
    lon=st.floats(-180.0, 180.0),
    height_km=st.floats(-9.0, 900.0),
    span=st.floats(0.0, 1.0),
)
def test_a_model_at_a_pole_is_the_field_beside_it(model, pole, lon, height_km, span):
    field_at, first, last = MODELS[model]
    year = first + span * (last - first)
    near = pole - NEAR_DEG if pole > 0 else pole + NEAR_DEG
    _same_field(field_at(pole, lon, year, height_km), field_at(near, lon, year, height_km))


def test_hil_replay_at_the_south_pole_uses_the_south_pole_s_field(tmp_path):
    """The command line, as a user meets it: the setup line names the field the replay turned its estimates
    by, the field beside the pole (declination −30.70°, inclination −72.12° at lon 0 in 2020)."""
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(FIXTURE), "--out", str(tmp_path / "out"), "--no-plots",
         "--lat", "-90", "--lon", "0", "--date", "2020-01-01"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    said = re.search(r"IGRF-14 at -90, 0, 2020.00: inclination (\S+) deg, declination (\S+) deg", run.stdout)
    assert said is not None, run.stdout
    near = igrf14(-90.0 + NEAR_DEG, 0.0, 2020.0)
    assert float(said[1]) == pytest.approx(near.inclination_deg, abs=0.01)
    assert float(said[2]) == pytest.approx(near.declination_deg, abs=0.01)

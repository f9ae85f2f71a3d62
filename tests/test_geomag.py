"""IGRF-14 (any recording date 1900–2030) against published values, WMM2025 and its own generator."""

from __future__ import annotations

import subprocess
import sys
from datetime import date

import pytest

from hil.estimation import igrf14_coefficients as table
from hil.estimation.geomag import igrf14, wmm2025
from hil.scenario.paths import ROOT
from protocol.errors import ConfigError


def test_igrf14_matches_a_published_igrf_value_at_a_definitive_epoch():
    # space-physics/igrf's test for IGRF-13 at 2010-07-12, 65 N 85 E, 0 km: 2010 lies between DGRF 2010
    # and DGRF 2015, definitive in both generations, so IGRF-14 must give the same field.
    f = igrf14(65.0, 85.0, date(2010, 7, 12), 0.0)
    assert (f.north_nT, f.east_nT, f.down_nT) == pytest.approx(
        (9295.415460, 2559.7889298, 59670.379598), abs=0.1
    )
    assert f.inclination_deg == pytest.approx(80.821575, abs=1e-4)
    assert f.declination_deg == pytest.approx(15.396590, abs=1e-4)


@pytest.mark.parametrize(
    ("year", "lat", "lon"), [(2025.0, 80.0, 0.0), (2026.5, 0.0, 120.0), (2028.0, -45.0, 240.0)]
)
def test_igrf14_and_wmm2025_agree_where_both_apply(year, lat, lon):
    a, b = igrf14(lat, lon, year), wmm2025(lat, lon, year)
    assert a.inclination_deg == pytest.approx(b.inclination_deg, abs=0.3)
    assert a.declination_deg == pytest.approx(b.declination_deg, abs=0.5)
    assert a.total_nT == pytest.approx(b.total_nT, rel=0.005)


def test_igrf14_covers_1900_to_2030_and_the_field_changed_over_the_century():
    old, new = igrf14(51.5, -0.1, 1900.0), igrf14(51.5, -0.1, 2020.0)  # London
    assert -18 < old.declination_deg < -15 and -1 < new.declination_deg < 1  # westerly 1900, ~0 in 2020
    igrf14(0.0, 0.0, 2030.0)
    for year in (1899.9, 2030.1):
        with pytest.raises(ConfigError, match="1900"):
            igrf14(0.0, 0.0, year)
    with pytest.raises(ConfigError, match="place"):
        igrf14(91.0, 0.0, 2000.0)


def test_the_coefficient_table_is_whole_and_the_generator_checks_it(tmp_path):
    assert table.EPOCHS[0] == 1900.0 and table.EPOCHS[-1] == 2030.0 and table.N_MAX == 13
    rows = table.TABLE.strip().splitlines()
    assert len(rows) == 13 * 15  # (n + 1) g and n h per degree n = 1..13
    assert rows[0].split()[:3] == ["1", "0", "-31543"]  # g10 of 1900
    shc = ["# IGRF 14", f"1 13 {len(table.EPOCHS)} 2 1 1900.0 2030.0", " ".join(map(str, table.EPOCHS))]
    (tmp_path / "IGRF14.shc").write_text("\n".join(shc + rows) + "\n")
    script = ROOT / "tools" / "igrf14_coefficients.py"
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "IGRF14.shc"), "--check"],
                         capture_output=True, text=True)  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    (tmp_path / "IGRF14.shc").write_text("\n".join(shc + rows[:-1] + [rows[-1] + "1"]) + "\n")
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "IGRF14.shc"), "--check"],
                         capture_output=True, text=True)  # fmt: skip
    assert out.returncode == 1

"""A rotor bench CSV whose battery parses but is below the maps' supply floor (1e-300 V, 0.5 V): the rotor
fit divides the speed by it. Refused naming the file, line and column, never fitted into a KV of 5e302
through the solver's overflow warnings, nor (one such row) misdiagnosed as a deadband."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.bench import read_bench_csv
from protocol.calibration import MIN_SUPPLY_V
from protocol.errors import InputFormatError

HIL = [sys.executable, "-m", "hil"]
SETTINGS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _rotor_csv(path: Path, volts: list[str]) -> Path:
    rows = [f"{1000 + 20 * i},{v},{max(0, 20 * i - 40) * 10}" for i, v in enumerate(volts)]
    path.write_text("# bench\npulse_us,battery_v,rpm\n" + "\n".join(rows) + "\n")
    return path


@SETTINGS
@given(
    low=st.floats(min_value=0.0, max_value=MIN_SUPPLY_V, exclude_min=True, exclude_max=True)
    | st.sampled_from([1e-300, 5e-324, 0.999]),
    at=st.integers(min_value=0, max_value=50),
)
def test_a_rotor_row_below_the_supply_floor_is_refused_naming_its_line(tmp_path, low, at):
    volts = ["12.5"] * 51
    volts[at] = repr(low)
    path = _rotor_csv(tmp_path / "rotor.csv", volts)
    with pytest.raises(InputFormatError) as info:
        read_bench_csv(path)
    assert str(info.value).startswith(f"{path}:{at + 3} (column battery_v): "), str(info.value)
    assert "no supply" in str(info.value)


def test_hil_calibrate_fit_of_a_rotor_sweep_at_1e_300_v_is_one_clear_error(tmp_path):
    """It was overflow warnings from the least-squares solver, then ``csv.kv_rad_s_per_v: 5.49e+302 is not
    a finite float32``."""
    path = _rotor_csv(tmp_path / "rotor.csv", ["1e-300"] * 51)
    out = tmp_path / "cal.toml"
    done = subprocess.run(
        [*HIL, "calibrate", "fit", str(path), "--base", "default", "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert (
        done.stderr == f"hil calibrate: error: {path}:3 (column battery_v): 1e-300 V is no supply (a rotor "
        "map reads below 1 V as none)\n"
    ), done.stderr
    assert not out.exists()

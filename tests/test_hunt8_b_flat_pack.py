"""``[board] soc = 0`` (a flat pack) was taken: the board shed its load at 0.16 s and ``hil run`` ended "time
limit (the slew never started)", exit 1, after 45 s of simulated waiting; ``soc = 0.05`` shed the rotors 54 s
in. Now a charge below :data:`~hil.scenario.reader.MIN_RUN_SOC` — where the pack's open-circuit voltage is
below the board's WARN stage — is refused as the file is read, naming ``board.soc``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board.config import BatteryParams, PowerThresholds
from firmware_sim.board.power_models import Battery
from hil.scenario import parse_scenario
from hil.scenario.reader import MIN_RUN_SOC
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]


def _open_circuit_cell_v(soc: float) -> float:
    params = BatteryParams(initial_soc=soc)
    return Battery(params).ocv() / params.cells


def test_the_floor_is_where_the_pack_rests_above_the_boards_warning():
    warn = PowerThresholds().warn_v_cell
    assert _open_circuit_cell_v(MIN_RUN_SOC) > warn
    assert _open_circuit_cell_v(MIN_RUN_SOC - 0.01) < warn


@settings(max_examples=40, deadline=None)
@given(soc=st.one_of(st.floats(0.0, MIN_RUN_SOC, exclude_max=True), st.just(0), st.just(-0.0)))
def test_a_pack_too_flat_to_fly_is_refused_naming_the_key(soc):
    with pytest.raises(ConfigError) as caught:
        parse_scenario(f"[scenario]\nname = 'flat'\n[board]\nsoc = {soc!r}\n", Path("flat.toml"))
    assert caught.value.where == "flat.toml: board.soc"
    assert f"at least {MIN_RUN_SOC:g}" in caught.value.detail


@settings(max_examples=20, deadline=None)
@given(soc=st.floats(MIN_RUN_SOC, 1.0))
def test_a_charged_pack_is_taken(soc):
    scenario = parse_scenario(f"[scenario]\nname = 'ok'\n[board]\nsoc = {soc!r}\n", Path("ok.toml"))
    assert scenario.board_options["soc"] == soc


def test_hil_run_refuses_a_flat_pack_in_one_line_before_it_runs(tmp_path):
    path = tmp_path / "flat.toml"
    path.write_text("[scenario]\nname = 'flat'\nduration_s = 3\n[board]\nsoc = 0\n")
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "flat.toml: board.soc:" in lines[0], lines

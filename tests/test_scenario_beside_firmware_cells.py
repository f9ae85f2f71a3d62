"""``[board] cells`` beyond what the C firmware's ADC reads, with the firmware board.

The firmware reads the battery through a 1/8 divider into its ADC's 2.56 V reference: 20.48 V at most
(``firmware/include/board_pins.h``). The scenario reader takes 2..12 cells (the Python board's range): with
the firmware board 6 full cells (25.2 V) read 20.456 V and 12 cells shed their load at once. Now a cell
count whose full pack is beyond the firmware's range is refused, naming ``[board] cells`` and the
firmware's limit, wherever a scenario is bound to the firmware board; the Python board keeps its range.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from hil.cli import main
from hil.scenario import parse_scenario
from hil.scenario.paths import FIXTURES, ROOT
from hil.scenario.reader import (
    CELL_FULL_V,
    FIRMWARE_BATTERY_FULL_SCALE_V,
    FIRMWARE_MAX_CELLS,
    check_firmware_board,
)
from protocol.errors import ConfigError

PINS = ROOT / "firmware" / "include" / "board_pins.h"


def _scenario_text(cells: int) -> str:
    text = (FIXTURES / "scenarios" / "cubesat-1u.toml").read_text()
    return text.replace("link_timeout = 0.25\n", f"link_timeout = 0.25\ncells = {cells}\n", 1)


def test_the_full_scale_is_the_firmwares():
    defines = dict(re.findall(r"#define (\w+) (\d+)u", PINS.read_text()))
    full_mv = (
        int(defines["ADC_REF_MV"]) * int(defines["BATTERY_DIVIDER_NUM"]) / int(defines["BATTERY_DIVIDER_DEN"])
    )
    assert FIRMWARE_BATTERY_FULL_SCALE_V == pytest.approx(full_mv / 1000.0)
    assert (
        FIRMWARE_MAX_CELLS * CELL_FULL_V
        <= FIRMWARE_BATTERY_FULL_SCALE_V
        < (FIRMWARE_MAX_CELLS + 1) * CELL_FULL_V
    )


@pytest.mark.parametrize("cells", [FIRMWARE_MAX_CELLS + 1, 6, 12])
def test_too_many_cells_for_the_firmware_board_are_refused_naming_the_key(cells):
    scenario = parse_scenario(_scenario_text(cells), Path("cells.toml"))  # the Python board's range: read
    check_firmware_board(scenario.with_board("emulator"))
    with pytest.raises(ConfigError) as caught:
        check_firmware_board(scenario.with_board("firmware"))
    assert caught.value.where == "cells.toml: board.cells"
    assert f"at most {FIRMWARE_MAX_CELLS} cells" in caught.value.detail and "20.48 V" in caught.value.detail


@pytest.mark.parametrize("cells", [2, FIRMWARE_MAX_CELLS])
def test_cells_within_the_firmwares_range_are_taken(cells):
    check_firmware_board(parse_scenario(_scenario_text(cells), Path("cells.toml")).with_board("firmware"))


def test_a_firmware_campaign_of_six_cells_is_refused_before_any_run(tmp_path, capsys):
    path = tmp_path / "cells6.toml"
    path.write_text(_scenario_text(6))
    out = tmp_path / "mc"
    argv = [
        "montecarlo",
        str(path),
        "--board",
        "firmware",
        "--runs",
        "1",
        "--duration",
        "1",
        "--out",
        str(out),
    ]
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2 and "cells6.toml: board.cells" in err and "Traceback" not in err, err
    assert not out.exists()


def test_hil_run_with_the_firmware_board_refuses_six_cells_before_it_starts(tmp_path, capsys):
    """``hil run --board firmware`` of a 6-cell scenario: the one line naming ``board.cells``, exit 2,
    nothing started (the check is :meth:`Scenario.with_board`'s, every path to the firmware board)."""
    path = tmp_path / "cells6.toml"
    path.write_text(_scenario_text(6))
    out = tmp_path / "runs"
    status = main(["run", "--scenario", str(path), "--board", "firmware", "--no-plots", "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2 and "board.cells" in err and "at most 4 cells" in err, err
    assert not out.exists() or not any(out.iterdir())


def test_firmware_sim_avr_refuses_six_cells():
    """``firmware-sim --avr --cells 6``: the firmware board's hardware check (firmware_sim.avr.eeprom),
    which every firmware board passes through, names the cells."""
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--avr", "--cells", "6", "--link", "unused"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2 and "cells" in done.stderr and "Traceback" not in done.stderr, done.stderr

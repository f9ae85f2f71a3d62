"""Runs of different scenarios compared (``hil gcs RUN_A RUN_B``): a run with more VSCMG units than the first
has every unit drawn.

The per-unit plots (gimbal angles and rates, rotor speeds, pulse widths) made their series from the first
run's unit count (``info.n_units``) and drew each run's columns of those: comparing the air-bearing
testbed's 3-unit tetrahedron (first) with the CubeSat's 4-unit pyramid left the pyramid's fourth unit out of
every per-unit plot and its legend, without a word — the comparison showed three of its four rotors. Now a
per-unit plot has a series for each unit any run compared has (a run without that unit draws none).

Through the real pieces: two real lockstep runs of the two scenarios, ``hil gcs A B``'s station, the page in
chromium; both orders.
"""

from __future__ import annotations

import re

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry
from hil.scenario import load_scenario

pytestmark = pytest.mark.browser

PER_UNIT = {"gimbal_angle": "γ", "gimbal_rate": "γ̇", "rotor": "Ω"}  # plot id: its series' label


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A 3-unit run (paper-testbed) and a 4-unit one (cubesat-1u), lockstep, 3 s each."""
    out = tmp_path_factory.mktemp("compare-units")
    return {
        scenario: run(load_scenario(scenario), RunOptions(out_root=out / scenario, duration_s=3.0)).run_dir
        for scenario in ("paper-testbed", "cubesat-1u")
    }


def _units(columns: list[str]) -> int:
    return sum(1 for c in columns if re.fullmatch(r"gimbal_angle_\d+", c))


@pytest.mark.parametrize("order", [("paper-testbed", "cubesat-1u"), ("cubesat-1u", "paper-testbed")])
def test_every_unit_of_every_run_compared_is_in_the_per_unit_plots(browser, runs, order):
    dirs = [runs[s] for s in order]
    tels = [read_telemetry(d / "telemetry.csv") for d in dirs]
    units = [_units(list(t.columns)) for t in tels]
    assert sorted(units) == [3, 4]
    with GroundStation.compare(dirs, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        second = "const o = window.gcs.state.overlays[1]; return o && o.store.n"
        wait_for(lambda: js(browser, "return window.gcs.state.store?.n") == tels[0].rows, 30, "the first run")
        wait_for(lambda: js(browser, second) == tels[1].rows, 30, "the second run")
        for plot, symbol in PER_UNIT.items():
            legend = js(
                browser,
                "return [...document.querySelectorAll(`#plot-${arguments[0]} .u-legend .u-label`)]"
                ".map((e) => e.textContent)",
                plot,
            )
            for d, n in zip(dirs, units, strict=True):
                shown = sorted(x for x in legend if x.startswith(f"{symbol} ") and x.endswith(f" · {d.name}"))
                wanted = sorted(f"{symbol} {k + 1} · {d.name}" for k in range(n))
                assert shown == wanted, (plot, d.name, legend)
    assert not page_errors(browser)
